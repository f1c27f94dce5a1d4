"""Taxi with fuel (Dietterich, 1998; dissertation Section 5.2.1) as a torch-batched env.

## Description
Dietterich's 5x5 taxi map (``envs.taxi``) with a fuel station F at row 3, column 2::

    +---------+
    |R: | : :G|
    | : | : : |
    | : : : : |
    | | :F| : |
    |Y| : |B: |
    +---------+

The taxi starts on a random square with 5 to 12 units of fuel (uniform), the passenger at a
random station and the destination at another station. Each move consumes one unit of fuel,
even into a wall; Fillup at F fills the tank to 12 units (``CAPACITY``).

## Action Space
``Discrete(7)``: 0 south, 1 north, 2 east, 3 west, 4 pickup, 5 dropoff, 6 fillup.

## Observation
``observation`` = ``fuel * 500 + taxi_state`` with ``taxi_state`` gymnasium's Taxi index
(``envs.taxi.encode``), ``fuel`` in 0..12: 13 x 500 = 6,500 values. Fields: those of
``envs.taxi`` plus ``fuel`` (0-12), and ``out_of_fuel`` (bool, not a declared space).

The dissertation counts 8,750 states. 8,750 / 500 = 17.5 fuel levels, so no fuel range on top
of the 500 taxi states gives it; 8,750 = 14 x 625 = 14 x 25 x (5 x 5) suggests 14 fuel levels
(0..12 plus an "empty" level) with a 5 x 5 passenger x destination block, but the destination
has only 4 values. We do not pad the index with unreachable values: running dry is reported by
``terminated`` and ``out_of_fuel`` and the last observation shows fuel 0.

## Rewards
As in ``envs.taxi`` (a special reward replaces the -1 of the step): -1 per action, +20 for the
delivery, -10 for an illegal Pickup or Dropoff, -10 for an illegal Fillup (one away from F; at
F with a full tank Fillup is legal, -1), -20 for the move that takes the fuel below zero.

## Episode End
Terminated on delivery or when the fuel falls below zero; truncated after 200 steps (as
``Taxi-v4``; Pickup, Dropoff and Fillup use no fuel, so without a limit a policy could loop).

## Version History
* v0: Section 5.2.1; fuel station position from Dietterich's figure, Fillup and reward
  conventions as above.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import torch

from envs import taxi
from hrl_torch.env.batched import BatchedEnv

FUEL_STATION = (3, 2)
CAPACITY = 12
START_FUEL = (5, 12)  # inclusive
N_FUEL = CAPACITY + 1
N_STATES = N_FUEL * taxi.N_STATES  # 6,500
N_ACTIONS = 7
SOUTH, NORTH, EAST, WEST, PICKUP, DROPOFF, FILLUP = range(7)
MAX_EPISODE_STEPS = 200
ILLEGAL_REWARD = -10.0
OUT_OF_FUEL_REWARD = -20.0


def encode(row: int, col: int, passenger: int, destination: int, fuel: int) -> int:
    """Flat state index ``fuel * 500 + taxi_state``."""
    return fuel * taxi.N_STATES + taxi.encode(row, col, passenger, destination)


@lru_cache(maxsize=1)
def transition_tables() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(next_state, reward, terminated)`` as ``[6500, 7]`` tables and the ``[2400]`` starts.

    Built from ``envs.taxi.transition_tables`` and the fuel rules in the module docstring.
    """
    taxi_next, taxi_reward, taxi_terminated, taxi_starts = taxi.transition_tables()
    fuel = torch.arange(N_FUEL)[:, None, None]  # [F, 1, 1]
    moves = (torch.arange(N_ACTIONS) < PICKUP)[None, None, :]  # [1, 1, A]
    at_station = torch.arange(taxi.N_STATES) // 20 == FUEL_STATION[0] * 5 + FUEL_STATION[1]
    at_station = at_station[None, :, None]

    pad = torch.arange(taxi.N_STATES)[:, None]  # Fillup leaves the taxi state unchanged
    next_taxi = torch.cat([taxi_next, pad], dim=1).expand(N_FUEL, -1, -1)
    reward = torch.cat([taxi_reward, torch.full((taxi.N_STATES, 1), -1.0)], dim=1)
    reward = reward.expand(N_FUEL, -1, -1).clone()
    terminated = torch.cat([taxi_terminated, torch.zeros(taxi.N_STATES, 1, dtype=torch.bool)], 1)
    terminated = terminated.expand(N_FUEL, -1, -1).clone()

    is_fillup = torch.arange(N_ACTIONS)[None, None, :] == FILLUP
    next_fuel = torch.where(moves, fuel - 1, fuel)
    next_fuel = torch.where(is_fillup & at_station, torch.tensor(CAPACITY), next_fuel)
    reward[(is_fillup & ~at_station).expand_as(reward)] = ILLEGAL_REWARD
    dry = next_fuel < 0
    reward[dry.expand_as(reward)] = OUT_OF_FUEL_REWARD
    terminated |= dry
    next_state = next_fuel.clamp_min(0) * taxi.N_STATES + next_taxi
    starts = torch.arange(START_FUEL[0], START_FUEL[1] + 1)[:, None] * taxi.N_STATES + taxi_starts
    return (
        next_state.reshape(N_STATES, N_ACTIONS),
        reward.reshape(N_STATES, N_ACTIONS),
        terminated.reshape(N_STATES, N_ACTIONS),
        starts.reshape(-1),
    )


def decode(state: torch.Tensor) -> dict[str, torch.Tensor]:
    """Observation fields of flat state indices (any shape)."""
    state = state.long()
    fields = taxi.decode(state % taxi.N_STATES)
    fields.update(observation=state, fuel=state // taxi.N_STATES)
    return fields


class TaxiFuelEnv(BatchedEnv):
    """Torch-batched taxi-fuel-earlier (see the module docstring).

    Args:
        seeds: one seed per learner.
        envs_per_learner: envs per learner ``E``.
        max_episode_steps: time limit (200).
        device: where the state lives.
    """

    state_keys = ("state", "out_of_fuel")
    observation_sizes = {
        "observation": N_STATES,
        "taxi_row": 5,
        "taxi_col": 5,
        "taxi_loc": 25,
        "passenger": 5,
        "destination": 4,
        "fuel": N_FUEL,
    }
    transition_tables = staticmethod(transition_tables)  # (a variant's own tables)
    decode = staticmethod(decode)

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        max_episode_steps: int | None = MAX_EPISODE_STEPS,
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__(seeds, envs_per_learner, N_ACTIONS, max_episode_steps, device)
        next_state, reward, terminated, starts = self.transition_tables()
        self.next_state = next_state.to(self.device)
        self.reward_table = reward.to(self.device)
        self.terminal_table = terminated.to(self.device)
        self.starts = starts.to(self.device)
        self.state = torch.zeros(self.batch_size, dtype=torch.long, device=self.device)
        self.out_of_fuel = torch.zeros(self.batch_size, dtype=torch.bool, device=self.device)

    def _reset_rows(self, mask: torch.Tensor) -> None:
        fresh = self.starts[self.rng.integers(len(self.starts))]
        self.state = torch.where(mask, fresh, self.state)
        self.out_of_fuel = self.out_of_fuel & ~mask

    def _step_all(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        reward = self.reward_table[self.state, action]
        terminated = self.terminal_table[self.state, action]
        self.out_of_fuel = terminated & (action < PICKUP)  # a move can only end by running dry
        self.state = self.next_state[self.state, action]
        return reward, torch.ones_like(reward), terminated

    def _observe(self) -> dict[str, torch.Tensor]:
        fields = self.decode(self.state)
        fields["out_of_fuel"] = self.out_of_fuel.clone()
        return fields


def gymnasium_env(render_mode: str | None = None):
    """``gymnasium.make("hrl/TaxiFuel-v0")``: one row of ``TaxiFuelEnv``."""
    from hrl_torch.env.adapters import BatchedToGymnasium

    return BatchedToGymnasium(lambda seeds, n: TaxiFuelEnv(seeds, n), render_mode=render_mode)
