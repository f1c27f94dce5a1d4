"""Dietterich's taxi as a torch-batched env, equal to gymnasium's ``Taxi-v4``.

## Description
A 5x5 grid with four stations R(0,0), G(0,4), Y(4,0), B(4,3)::

    +---------+
    |R: | : :G|
    | : | : : |
    | : : : : |
    | | : | : |
    |Y| : |B: |
    +---------+

The taxi starts on a random square, the passenger at a random station and the destination at
another station. The taxi must pick the passenger up and drop them at the destination.

## Action Space
``Discrete(6)``: 0 south, 1 north, 2 east, 3 west, 4 pickup, 5 dropoff.

## Observation
A TensorDict with ``observation`` (gymnasium's state index
``((row * 5 + col) * 5 + passenger) * 4 + destination``, 500 values) and its decoded fields
``taxi_row``, ``taxi_col``, ``taxi_loc`` (``row * 5 + col``), ``passenger`` (0-3 a station,
4 in the taxi) and ``destination`` (0-3).

## Rewards
-1 per step, +20 for delivering the passenger, -10 for an illegal pickup or dropoff. Dropping
the passenger at a station other than the destination leaves them there (reward -1), as in
gymnasium.

## Episode End
Terminated on delivery; truncated after 200 steps (gymnasium's ``TimeLimit``).

## Version History
* v0: dynamics, rewards, start distribution and time limit of gymnasium ``Taxi-v4``
  (deterministic: ``is_rainy=False``, ``fickle_passenger=False``).
"""

from __future__ import annotations

from functools import lru_cache

import torch

from envs.grid import TableEnv

MAP = (
    "+---------+",
    "|R: | : :G|",
    "| : | : : |",
    "| : : : : |",
    "| | : | : |",
    "|Y| : |B: |",
    "+---------+",
)
STATIONS = ((0, 0), (0, 4), (4, 0), (4, 3))
N_STATES = 500
N_ACTIONS = 6
SOUTH, NORTH, EAST, WEST, PICKUP, DROPOFF = range(6)
MAX_EPISODE_STEPS = 200


def encode(row: int, col: int, passenger: int, destination: int) -> int:
    """Gymnasium's state index."""
    return ((row * 5 + col) * 5 + passenger) * 4 + destination


@lru_cache(maxsize=1)
def transition_tables() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(next_state, reward, terminated)`` as ``[500, 6]`` tables, and the ``[300]`` start states.

    Built from the map and the rules in the module docstring.
    """
    next_state = torch.zeros(N_STATES, N_ACTIONS, dtype=torch.long)
    reward = torch.full((N_STATES, N_ACTIONS), -1.0)
    terminated = torch.zeros(N_STATES, N_ACTIONS, dtype=torch.bool)
    starts = []
    for row in range(5):
        for col in range(5):
            for passenger in range(5):
                for destination in range(4):
                    s = encode(row, col, passenger, destination)
                    if passenger < 4 and passenger != destination:
                        starts.append(s)
                    for action in range(N_ACTIONS):
                        r, c, p = row, col, passenger
                        if action == SOUTH:
                            r = min(row + 1, 4)
                        elif action == NORTH:
                            r = max(row - 1, 0)
                        elif action == EAST and MAP[1 + row][2 * col + 2] == ":":
                            c = min(col + 1, 4)
                        elif action == WEST and MAP[1 + row][2 * col] == ":":
                            c = max(col - 1, 0)
                        elif action == PICKUP:
                            if passenger < 4 and (row, col) == STATIONS[passenger]:
                                p = 4
                            else:
                                reward[s, action] = -10.0
                        elif action == DROPOFF:
                            if passenger == 4 and (row, col) == STATIONS[destination]:
                                p = destination
                                reward[s, action] = 20.0
                                terminated[s, action] = True
                            elif passenger == 4 and (row, col) in STATIONS:
                                p = STATIONS.index((row, col))
                            else:
                                reward[s, action] = -10.0
                        next_state[s, action] = encode(r, c, p, destination)
    return next_state, reward, terminated, torch.tensor(starts, dtype=torch.long)


def decode(state: torch.Tensor) -> dict[str, torch.Tensor]:
    """Observation fields of gymnasium state indices (any shape)."""
    state = state.long()
    destination = state % 4
    passenger = (state // 4) % 5
    taxi_loc = state // 20
    return {
        "observation": state,
        "taxi_row": taxi_loc // 5,
        "taxi_col": taxi_loc % 5,
        "taxi_loc": taxi_loc,
        "passenger": passenger,
        "destination": destination,
    }


class TaxiEnv(TableEnv):
    """Torch-batched ``Taxi-v4`` (see the module docstring).

    Arguments as ``envs.grid.TableEnv`` (its time limit: ``MAX_EPISODE_STEPS``).
    """

    observation_sizes = {
        "observation": N_STATES,
        "taxi_row": 5,
        "taxi_col": 5,
        "taxi_loc": 25,
        "passenger": 5,
        "destination": 4,
    }

    time_limit = MAX_EPISODE_STEPS
    transition_tables = staticmethod(transition_tables)
    decode = staticmethod(decode)


def gymnasium_env(render_mode: str | None = None):
    """``gymnasium.make("hrl/Taxi-v0")``: one row of ``TaxiEnv`` as a gymnasium env."""
    from hrl_torch.env.adapters import BatchedToGymnasium

    return BatchedToGymnasium(lambda seeds, n: TaxiEnv(seeds, n), render_mode=render_mode)
