"""The small AGV scheduling task of Section 4.3.1 (Figure 4.2) as a torch-batched env.

## Description
Machines M1 and M2 stand in the machine room, destination stations G1 and G2 in the goal
room; the AGV changes rooms only through door D1 or D2. A partition wall with one opening
(column 0) splits the machine room, so inside it M1 (next to D1) is far from D2 and M2 (next to
D2) is far from D1, while in the small goal room G1 sits at D2 and G2 at D1::

          0   1   2   3   4   5   6   7   8
        +-----------------------+---+-------+
      0 | .   .   .   .   M1  .   D1  G2  . |
        |                       +---+       |
      1 | .   .   .   .   .   . |###| .   . |
        |   +-------------------+---+       |
      2 | .   .   .   .   M2  .   D2  G1  . |
        +-----------------------+---+-------+

26 locations (18 in the machine room, 2 doors, 6 in the goal room) x 3 AGV statuses (empty,
carrying part 1, carrying part 2) = 78 states. The task is deterministic and continuing.
Distances that matter: M1 -> G1 takes 5 moves (through D1), and so does G1 -> M1 through D1;
but the door nearest to G1 is D2 (2 moves back into the machine room, against 4 through D1),
and from there M1 is 11 moves away inside the machine room (M2 is 1). With the task graph of
``agents.small_agv`` this makes the hierarchically optimal policy (always serve M1, gain 0.75)
differ from the recursively optimal one (alternate M1 and M2, gain 0.15).

## Action Space
``Discrete(6)``: 0 south, 1 north, 2 east, 3 west, 4 load, 5 unload. Moving into a wall leaves
the AGV in place. ``load`` at M1 or M2 with an empty AGV takes that machine's part; ``unload``
of part ``i`` at ``Gi`` delivers it; elsewhere both do nothing.

## Observation
A TensorDict with ``observation`` (state index ``location * 3 + status``, 78 values) and its
fields ``location`` (26, row-major over the map), ``status`` (0 empty, 1 part 1, 2 part 2),
``row`` (3), ``col`` (9), ``room`` (0 machine room, 1 door, 2 goal room), plus ``delivered``
(0 none, 1 part 1, 2 part 2): the part the last step delivered, for the throughput metric.

## Rewards
+20 for delivering part 1 at G1, +1 for delivering part 2 at G2, -1 for every other action.
Throughput (Figure 4.3) is ``20 * part1 + 1 * part2`` deliveries per 10,000 steps
(``throughput``, or exactly ``10_000 * gain`` under ``delivery_weight_table()``).

## Starting State
Empty AGV at a uniformly random machine-room location.

## Episode End
None: the task is continuing (never terminated, no time limit unless one is asked for).

## Version History
* v0: layout reconstructed from the text of Section 4.3.1 (the figure is not in the text).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import torch

from hrl_torch.common.devices import constant_on
from hrl_torch.env.batched import BatchedEnv

MAP = (
    "+-----------------------+---+-------+",
    "| .   .   .   .   M1  .   D1  G2  . |",
    "|                       +---+       |",
    "| .   .   .   .   .   . |###| .   . |",
    "|   +-------------------+---+       |",
    "| .   .   .   .   M2  .   D2  G1  . |",
    "+-----------------------+---+-------+",
)
N_ROWS, N_COLS = 3, 9
N_STATUS = 3
EMPTY, PART1, PART2 = range(3)
SOUTH, NORTH, EAST, WEST, LOAD, UNLOAD = range(6)
N_ACTIONS = 6
MACHINE_ROOM, DOOR, GOAL_ROOM = range(3)
#: weight of a delivery of each ``delivered`` value in the throughput (Figure 4.3)
DELIVERY_WEIGHT = torch.tensor([0.0, 20.0, 1.0])
_STEP = {SOUTH: (1, 0), NORTH: (-1, 0), EAST: (0, 1), WEST: (0, -1)}


def _center(row: int, col: int) -> tuple[int, int]:
    """Text position of a cell's first character in ``MAP``."""
    return 1 + 2 * row, 2 + 4 * col


def _parse_map():
    cells = [
        (r, c)
        for r in range(N_ROWS)
        for c in range(N_COLS)
        if MAP[_center(r, c)[0]][_center(r, c)[1]] != "#"
    ]
    index = {rc: k for k, rc in enumerate(cells)}
    labels = {}
    for k, (r, c) in enumerate(cells):
        line, pos = _center(r, c)
        text = MAP[line][pos : pos + 2].strip(". ")
        if text:
            labels[text] = k

    def open_between(a: tuple[int, int], b: tuple[int, int]) -> bool:
        if b not in index:
            return False
        (r1, c1), (r2, c2) = sorted((a, b))
        line, pos = _center(r1, c1)
        wall = MAP[line + 1][pos] if r2 > r1 else MAP[line][pos + 2]
        return wall == " "

    move = [[k] * 4 for k in range(len(cells))]  # move[loc][action] for the four moves
    for k, (r, c) in enumerate(cells):
        for action, (dr, dc) in _STEP.items():
            target = (r + dr, c + dc)
            if open_between((r, c), target):
                move[k][action] = index[target]
    return cells, labels, move


CELLS, LABELS, _MOVES_OF = _parse_map()
N_LOCATIONS = len(CELLS)
N_STATES = N_LOCATIONS * N_STATUS
M1, M2, G1, G2, D1, D2 = (LABELS[k] for k in ("M1", "M2", "G1", "G2", "D1", "D2"))
MACHINES = (M1, M2)  # machine of part 1, part 2
GOALS = (G1, G2)  # destination of part 1, part 2


def _rooms() -> tuple[int, ...]:
    """Room of every location: flood fill from M1 and G1 without crossing the doors."""
    room = [DOOR if k in (D1, D2) else -1 for k in range(N_LOCATIONS)]
    for seed, label in ((M1, MACHINE_ROOM), (G1, GOAL_ROOM)):
        frontier = [seed]
        while frontier:
            k = frontier.pop()
            if room[k] == -1:
                room[k] = label
                frontier.extend(_MOVES_OF[k])
    return tuple(room)


ROOM = _rooms()
#: ``[26, 4]`` long: location reached by south, north, east, west from every location
MOVE_TARGET = torch.tensor(_MOVES_OF)
#: ``[26]`` long: room of every location (``MACHINE_ROOM``, ``DOOR`` or ``GOAL_ROOM``)
ROOM_OF = torch.tensor(ROOM)
MACHINE_ROOM_LOCATIONS = torch.tensor([k for k in range(N_LOCATIONS) if ROOM[k] == MACHINE_ROOM])


def encode(location: int, status: int) -> int:
    """State index of an AGV location and status."""
    return location * N_STATUS + status


@lru_cache(maxsize=1)
def _tables() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    next_state = torch.zeros(N_STATES, N_ACTIONS, dtype=torch.long)
    reward = torch.full((N_STATES, N_ACTIONS), -1.0)
    delivered = torch.zeros(N_STATES, N_ACTIONS, dtype=torch.long)
    for loc in range(N_LOCATIONS):
        for status in range(N_STATUS):
            s = encode(loc, status)
            for action in range(N_ACTIONS):
                where, carry = loc, status
                if action in _STEP:
                    where = _MOVES_OF[loc][action]
                elif action == LOAD and status == EMPTY and loc in MACHINES:
                    carry = MACHINES.index(loc) + 1
                elif action == UNLOAD and status != EMPTY and loc == GOALS[status - 1]:
                    carry = EMPTY
                    delivered[s, action] = status
                    reward[s, action] = float(DELIVERY_WEIGHT[status])
                next_state[s, action] = encode(where, carry)
    return next_state, reward, delivered


def transition_tables() -> tuple[torch.Tensor, torch.Tensor]:
    """The exact model: ``(next_state [78, 6] long, reward [78, 6])``."""
    next_state, reward, _ = _tables()
    return next_state.clone(), reward.clone()


def delivery_table() -> torch.Tensor:
    """``[78, 6]`` long: the part (1 or 2) a step delivers, 0 for none."""
    return _tables()[2].clone()


def delivery_weight_table() -> torch.Tensor:
    """``[78, 6]``: throughput weight of each step (20 for part 1, 1 for part 2).

    A policy's gain under this table, times 10,000, is its throughput in Figure 4.3.
    """
    return DELIVERY_WEIGHT[_tables()[2]]


def throughput(delivered: torch.Tensor) -> torch.Tensor:
    """Weighted deliveries per 10,000 steps from ``delivered [T, ...]`` recorded over T steps."""
    weights = constant_on(DELIVERY_WEIGHT, delivered.device)
    return weights[delivered].sum(0) * (10_000 / delivered.shape[0])


_ROW = torch.tensor([r for r, _ in CELLS])
_COL = torch.tensor([c for _, c in CELLS])


def decode(state: torch.Tensor) -> dict[str, torch.Tensor]:
    """Observation fields of state indices (any shape); ``delivered`` is not a state field."""
    state = state.long()
    location = state // N_STATUS
    return {
        "observation": state,
        "location": location,
        "status": state % N_STATUS,
        "row": constant_on(_ROW, state.device)[location],
        "col": constant_on(_COL, state.device)[location],
        "room": constant_on(ROOM_OF, state.device)[location],
    }


class SmallAGVEnv(BatchedEnv):
    """Torch-batched small AGV task (see the module docstring).

    Args:
        seeds: one seed per learner.
        envs_per_learner: envs per learner ``E``; the batch is ``len(seeds) * E``.
        max_episode_steps: optional time limit; the task itself is continuing (default none).
        device: where the state lives.
    """

    state_keys = ("state", "delivered")
    observation_sizes = {
        "observation": N_STATES,
        "location": N_LOCATIONS,
        "status": N_STATUS,
        "row": N_ROWS,
        "col": N_COLS,
        "room": 3,
        "delivered": 3,
    }

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        max_episode_steps: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__(seeds, envs_per_learner, N_ACTIONS, max_episode_steps, device)
        next_state, reward, delivered = _tables()
        self.next_state = next_state.to(self.device)
        self.reward_table = reward.to(self.device)
        self.delivered_table = delivered.to(self.device)
        self.state = torch.zeros(self.batch_size, dtype=torch.long, device=self.device)
        self.delivered = torch.zeros_like(self.state)
        self.starts = MACHINE_ROOM_LOCATIONS.to(self.device) * N_STATUS + EMPTY

    def _reset_rows(self, mask: torch.Tensor) -> None:
        fresh = self.starts[self.rng.integers(len(self.starts))]
        self.state = torch.where(mask, fresh, self.state)
        self.delivered = torch.where(mask, torch.zeros_like(self.delivered), self.delivered)

    def _step_all(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        reward = self.reward_table[self.state, action]
        self.delivered = self.delivered_table[self.state, action]
        self.state = self.next_state[self.state, action]
        return reward, torch.ones_like(reward), torch.zeros_like(self.state, dtype=torch.bool)

    def _observe(self) -> dict[str, torch.Tensor]:
        return {**decode(self.state), "delivered": self.delivered}


def gymnasium_env(render_mode: str | None = None):
    """``gymnasium.make("hrl/SmallAGV-v0")``: one row of ``SmallAGVEnv`` as a gymnasium env."""
    from hrl_torch.env.adapters import BatchedToGymnasium

    return BatchedToGymnasium(lambda seeds, n: SmallAGVEnv(seeds, n), render_mode=render_mode)
