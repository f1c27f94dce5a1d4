"""A locked door between two rooms: fetch the key, unlock the door, walk to the goal.

## Description
Two 5 x 4 rooms split by a wall whose only opening, the door ``D``, starts locked::

        0 1 2 3 4 5 6 7 8
      0 k . k . # . . . g
      1 . . . . # . . . .
      2 . . . u D . . . .
      3 . . . . # . . . .
      4 k . k . # . . . g

The key lies on one of the four ``k`` spots and the goal is one of the two ``g`` cells, both
drawn at every reset. The agent picks the key up on its spot and unlocks the door from ``u``,
the cell west of it (the key is used up); the door cell is then free to cross.

41 free cells x 6 key states (on spot 0-3, held, used) x 2 goals = 492 states.

## Action Space
``Discrete(6)``: 0 north, 1 south, 2 east, 3 west, 4 pickup, 5 unlock. A move into a wall or
the locked door leaves the agent in place.

## Observation
A TensorDict with ``observation`` (``(cell * 6 + key) * 2 + goal``, 492 values) and its fields
``cell`` (41, row-major over the free cells), ``key`` (0-3 on that spot, 4 held, 5 used: the
door is open), ``goal`` (2), ``row`` (5) and ``col`` (9).

## Rewards
-1 per action; -10 for a pickup where the key is not, or an unlock without the key or away
from ``u`` (as taxi's illegal pickup and dropoff).

## Starting State
A uniformly random cell of the left room (20), key spot (4) and goal (2): 160 start states.

## Episode End
Terminated on reaching the goal; truncated after 200 steps.

## Version History
* v0: this layout and these rules.
"""

from __future__ import annotations

from functools import lru_cache

import torch

from envs.grid import TableEnv, free_cells, move_table
from hrl_torch.common.devices import constant_on

LAYOUT = (
    "....#....",
    "....#....",
    "....D....",
    "....#....",
    "....#....",
)
CELLS = free_cells(LAYOUT)
N_CELLS = len(CELLS)  # 41
KEY_SPOTS = ((0, 0), (4, 0), (0, 2), (4, 2))
DOOR = (2, 4)
UNLOCK_CELL = (2, 3)
GOALS = ((0, 8), (4, 8))
HELD, USED = 4, 5
N_KEY = 6
N_GOALS = len(GOALS)
N_STATES = N_CELLS * N_KEY * N_GOALS  # 492
N_ACTIONS = 6
NORTH, SOUTH, EAST, WEST, PICKUP, UNLOCK = range(6)
ILLEGAL_REWARD = -10.0
MAX_EPISODE_STEPS = 200


def cell_index(row: int, col: int) -> int:
    """Index of the free cell ``(row, col)``."""
    return CELLS.index((row, col))


def encode(row: int, col: int, key: int, goal: int) -> int:
    """State index ``(cell * 6 + key) * 2 + goal``."""
    return (cell_index(row, col) * N_KEY + key) * N_GOALS + goal


@lru_cache(maxsize=1)
def transition_tables() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(next_state, reward, terminated)`` ``[492, 6]`` and the ``[160]`` start states."""
    moves = move_table(LAYOUT)
    door = cell_index(*DOOR)
    next_state = torch.zeros(N_STATES, N_ACTIONS, dtype=torch.long)
    reward = torch.full((N_STATES, N_ACTIONS), -1.0)
    terminated = torch.zeros(N_STATES, N_ACTIONS, dtype=torch.bool)
    starts = []
    for cell, (row, col) in enumerate(CELLS):
        for key in range(N_KEY):
            for goal in range(N_GOALS):
                s = (cell * N_KEY + key) * N_GOALS + goal
                if col < DOOR[1] and key < HELD:
                    starts.append(s)
                for action in range(N_ACTIONS):
                    to, k = cell, key
                    if action < 4:
                        to = int(moves[cell, action])
                        if to == door and key != USED:  # locked
                            to = cell
                    elif action == PICKUP:
                        if key < HELD and (row, col) == KEY_SPOTS[key]:
                            k = HELD
                        else:
                            reward[s, action] = ILLEGAL_REWARD
                    elif key == HELD and (row, col) == UNLOCK_CELL:
                        k = USED
                    else:
                        reward[s, action] = ILLEGAL_REWARD
                    next_state[s, action] = (to * N_KEY + k) * N_GOALS + goal
                    terminated[s, action] = CELLS[to] == GOALS[goal]
    return next_state, reward, terminated, torch.tensor(starts)


_ROW_COL = torch.tensor(CELLS)  # [41, 2]


def decode(state: torch.Tensor) -> dict[str, torch.Tensor]:
    """Observation fields of state indices (any shape)."""
    state = state.long()
    cell = state // (N_KEY * N_GOALS)
    rc = constant_on(_ROW_COL, state.device)[cell]
    return {
        "observation": state,
        "cell": cell,
        "key": (state // N_GOALS) % N_KEY,
        "goal": state % N_GOALS,
        "row": rc[..., 0],
        "col": rc[..., 1],
    }


class KeyDoorEnv(TableEnv):
    """Torch-batched key and door (see the module docstring).

    Arguments as ``envs.grid.TableEnv`` (its time limit: ``MAX_EPISODE_STEPS``).
    """

    observation_sizes = {
        "observation": N_STATES,
        "cell": N_CELLS,
        "key": N_KEY,
        "goal": N_GOALS,
        "row": len(LAYOUT),
        "col": len(LAYOUT[0]),
    }

    time_limit = MAX_EPISODE_STEPS
    transition_tables = staticmethod(transition_tables)
    decode = staticmethod(decode)


def gymnasium_env(render_mode: str | None = None):
    """``gymnasium.make("hrl/KeyDoor-v0")``: one row of ``KeyDoorEnv`` as a gymnasium env."""
    return KeyDoorEnv.gymnasium(render_mode)
