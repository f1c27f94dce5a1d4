"""Sutton, Precup and Singh's four rooms (1999) with a goal that changes every episode.

## Description
Four rooms joined by four one-cell hallways (``0``-``3``); the goal is one of four cells,
``A`` to ``D``, one in a corner of each room, drawn at every reset and observed::

        0 1 2 3 4 5 6 7 8 9 10 11 12
      0 # # # # # # # # # # #  #  #
      1 # A . . . . # . . . .  B  #
      2 # . . . . . # . . . .  .  #
      3 # . . . . . 0 . . . .  .  #
      4 # . . . . . # . . . .  .  #
      5 # . . . . . # . . . .  .  #
      6 # # 1 # # # # . . . .  .  #
      7 # . . . . . # # # 2 #  #  #
      8 # . . . . . # . . . .  .  #
      9 # . . . . . # . . . .  .  #
     10 # . . . . . 3 . . . .  .  #
     11 # C . . . . # . . . .  D  #
     12 # # # # # # # # # # #  #  #

104 free cells (rooms of 25, 30, 25 and 20 cells, and the hallways) x 4 goals = 416 states.

## Action Space
``Discrete(4)``: 0 north, 1 south, 2 east, 3 west (deterministic; into a wall: no move).

## Observation
A TensorDict with ``observation`` (state index ``cell * 4 + goal``, 416 values) and its
fields ``cell`` (104, row-major over the free cells), ``goal`` (4), ``row`` and ``col`` (13)
and ``region`` (0-3 the rooms top-left, top-right, bottom-left, bottom-right; 4-7 the
hallways 0-3).

## Rewards
-1 per step, the step onto the goal included.

## Starting State
A uniformly random goal and a uniformly random free cell other than the goal.

## Episode End
Terminated on reaching the goal; truncated after 100 steps (the longest shortest path is 20).

## Version History
* v0: the layout of Sutton, Precup and Singh (1999, Figure 2), goals in the room corners.
"""

from __future__ import annotations

from functools import lru_cache

import torch

from envs.grid import TableEnv, free_cells, move_table
from hrl_torch.common.devices import constant_on

LAYOUT = (
    "#############",
    "#     #     #",
    "#     #     #",
    "#           #",
    "#     #     #",
    "#     #     #",
    "## ####     #",
    "#     ### ###",
    "#     #     #",
    "#     #     #",
    "#           #",
    "#     #     #",
    "#############",
)
CELLS = free_cells(LAYOUT)
N_CELLS = len(CELLS)  # 104
HALLWAYS = ((3, 6), (6, 2), (7, 9), (10, 6))
GOALS = ((1, 1), (1, 11), (11, 1), (11, 11))
N_GOALS = len(GOALS)
N_STATES = N_CELLS * N_GOALS  # 416
N_ACTIONS = 4
N_REGIONS = 8  # four rooms, four hallways
#: the two rooms each hallway joins
HALLWAY_ROOMS = ((0, 1), (0, 2), (1, 3), (2, 3))
MAX_EPISODE_STEPS = 100


def cell_index(row: int, col: int) -> int:
    """Index of the free cell ``(row, col)``."""
    return CELLS.index((row, col))


def region_of(row: int, col: int) -> int:
    """Room (0 top-left, 1 top-right, 2 bottom-left, 3 bottom-right) or 4 + hallway."""
    if (row, col) in HALLWAYS:
        return 4 + HALLWAYS.index((row, col))
    if col < 6:
        return 0 if row < 6 else 2
    return 1 if row < 7 else 3


def encode(row: int, col: int, goal: int) -> int:
    """State index ``cell * 4 + goal``."""
    return cell_index(row, col) * N_GOALS + goal


@lru_cache(maxsize=1)
def transition_tables() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(next_state, reward, terminated)`` ``[416, 4]`` and the ``[412]`` start states."""
    moves = move_table(LAYOUT)
    goal_cell = torch.tensor([cell_index(*g) for g in GOALS])
    cell = torch.arange(N_CELLS).repeat_interleave(N_GOALS)  # [S]
    goal = torch.arange(N_GOALS).repeat(N_CELLS)
    next_cell = moves[cell]  # [S, 4]
    next_state = next_cell * N_GOALS + goal[:, None]
    terminated = next_cell == goal_cell[goal][:, None]
    reward = torch.full((N_STATES, N_ACTIONS), -1.0)
    starts = torch.nonzero(cell != goal_cell[goal]).squeeze(1)
    return next_state, reward, terminated, starts


_ROW_COL = torch.tensor(CELLS)  # [104, 2]
_REGION = torch.tensor([region_of(r, c) for r, c in CELLS])


def decode(state: torch.Tensor) -> dict[str, torch.Tensor]:
    """Observation fields of state indices (any shape)."""
    state = state.long()
    cell = state // N_GOALS
    rc = constant_on(_ROW_COL, state.device)[cell]
    return {
        "observation": state,
        "cell": cell,
        "goal": state % N_GOALS,
        "row": rc[..., 0],
        "col": rc[..., 1],
        "region": constant_on(_REGION, state.device)[cell],
    }


class FourRoomsEnv(TableEnv):
    """Torch-batched four rooms (see the module docstring).

    Arguments as ``envs.grid.TableEnv`` (its time limit: ``MAX_EPISODE_STEPS``).
    """

    observation_sizes = {
        "observation": N_STATES,
        "cell": N_CELLS,
        "goal": N_GOALS,
        "row": len(LAYOUT),
        "col": len(LAYOUT[0]),
        "region": N_REGIONS,
    }

    time_limit = MAX_EPISODE_STEPS
    transition_tables = staticmethod(transition_tables)
    decode = staticmethod(decode)


def gymnasium_env(render_mode: str | None = None):
    """``gymnasium.make("hrl/FourRooms-v0")``: one row of ``FourRoomsEnv`` as a gymnasium env."""
    return FourRoomsEnv.gymnasium(render_mode)
