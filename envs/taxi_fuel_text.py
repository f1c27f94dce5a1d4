"""Taxi-fuel with the dissertation's state space: 8,750 states, no time limit (Section 5.2.1).

## Why 8,750
The text gives the count but not its factors. With the taxi's 25 squares and the passenger's
5 locations (R, G, Y, B, in the taxi; Dietterich's count), 8,750 / (25 x 5) = 70 values are
left for the destination and the fuel together. The fuel needs at least 13 values (a start
fuel of up to 12 units, and 0), and 70 = 2 x 5 x 7 has one divisor from 13 to 34: 14. So the
fuel takes 14 values and the destination 5: 25 x 5 x 5 x 14 = 8,750. We read the 14 levels as
-1..12 (the text's "falls below zero" is a level of its own, the -20 state that ends the
episode; 12 is the largest start fuel and the tank's capacity), and the destination's 5 values
as the passenger's location code (R, G, Y, B, taxi) reused, whose fifth value never occurs.
(A 13-unit tank, fuel 0..13, gives 14 too; the text does not say which.)

## Observation
``observation`` = ``((taxi_loc * 5 + passenger) * 5 + destination) * 14 + fuel + 1``, each
factor's size in ``FACTORS`` (their product is ``N_STATES``). Fields: those of ``envs.taxi``,
``fuel_level`` (``fuel + 1``, 0..13), and ``fuel`` (-1..12) and ``out_of_fuel`` (bool), not
declared spaces.

## Rules (the text's; what differs from ``envs.taxi_fuel``)
The map, the fuel station F, the moves and Pickup are ``envs.taxi_fuel``'s. -1 per action,
+20 for the delivery, -10 for an illegal Pickup or Dropoff, -20 for the move that takes the
fuel below zero (to level -1). Changed:

- Dropoff is legal only at the destination ("drop off the passenger there"); anywhere else it
  is illegal (-10, the passenger stays aboard). Gymnasium's taxi, and so ``envs.taxi_fuel``,
  lets the passenger out at any station for -1: without a time limit, Get and Put could then
  trade the passenger back and forth at one station for ever, burning no fuel.
- Fillup away from F costs -1 and does nothing (the text names only Pickup and Dropoff as
  illegal; ``envs.taxi_fuel`` gives -10).
- No time limit (the text's episode ends at the delivery or when the fuel runs out). Rows of the
unused destination code are never reached: there every action leaves the state as it is (-1).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import torch

from envs import taxi
from envs.taxi_fuel import (
    CAPACITY,
    DROPOFF,
    FILLUP,
    FUEL_STATION,
    ILLEGAL_REWARD,
    N_ACTIONS,
    OUT_OF_FUEL_REWARD,
    PICKUP,
    START_FUEL,
    TaxiFuelEnv,
)

__all__ = ["CAPACITY", "FACTORS", "N_STATES", "TaxiFuelTextEnv", "decode", "encode"]

IN_TAXI = len(taxi.STATIONS)
EMPTY = -1  # the level below zero
#: the state's factors in index order (outermost first) and their number of values
FACTORS = {
    "taxi_loc": 5 * 5,
    "passenger": len(taxi.STATIONS) + 1,  # four stations and the taxi
    "destination": len(taxi.STATIONS) + 1,  # the same code; "taxi" never occurs
    "fuel_level": CAPACITY - EMPTY + 1,  # -1..12
}
N_STATES = math.prod(FACTORS.values())  # 8,750
FUEL_LOC = FUEL_STATION[0] * 5 + FUEL_STATION[1]


def encode(row: int, col: int, passenger: int, destination: int, fuel: int) -> int:
    """Flat index of a state (``fuel`` in -1..12)."""
    if not (0 <= row < 5 and 0 <= col < 5):
        raise ValueError(f"square ({row}, {col}) outside the 5 x 5 grid")
    index = 0
    values = (row * 5 + col, passenger, destination, fuel - EMPTY)
    for name, value in zip(FACTORS, values, strict=True):
        if not 0 <= value < FACTORS[name]:
            raise ValueError(f"{name} {value} outside 0..{FACTORS[name] - 1}")
        index = index * FACTORS[name] + value
    return index


def decode(state: torch.Tensor) -> dict[str, torch.Tensor]:
    """Observation fields of flat state indices (any shape)."""
    rest = state.long()
    values = {}
    for name in reversed(FACTORS):
        values[name] = rest % FACTORS[name]
        rest = rest // FACTORS[name]
    loc = values["taxi_loc"]
    return {
        "observation": state.long(),
        "taxi_row": loc // 5,
        "taxi_col": loc % 5,
        "taxi_loc": loc,
        "passenger": values["passenger"],
        "destination": values["destination"],
        "fuel_level": values["fuel_level"],
        "fuel": values["fuel_level"] + EMPTY,
    }


@lru_cache(maxsize=1)
def transition_tables() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(next_state, reward, terminated)`` as ``[8750, 7]`` tables and the ``[2400]`` starts."""
    taxi_next, taxi_reward, taxi_terminated, _ = taxi.transition_tables()
    f = decode(torch.arange(N_STATES))
    used = f["destination"] < IN_TAXI
    t = (f["taxi_loc"] * 5 + f["passenger"]) * 4 + f["destination"].clamp_max(IN_TAXI - 1)
    after = taxi.decode(taxi_next[t])  # [S, 6] fields after Dietterich's six actions
    moves = torch.arange(N_ACTIONS) < PICKUP
    fuel = f["fuel"][:, None]
    next_fuel = torch.where(moves, fuel - 1, fuel).clamp_min(EMPTY)  # navigation burns 1
    at_f = (f["taxi_loc"] == FUEL_LOC)[:, None] & (torch.arange(N_ACTIONS) == FILLUP)
    next_fuel = torch.where(at_f, CAPACITY, next_fuel)
    pad = lambda x, fill: torch.cat([x, fill[:, None]], 1)  # noqa: E731  (Fillup's column)
    loc = pad(after["taxi_loc"], f["taxi_loc"])
    passenger = pad(after["passenger"], f["passenger"])
    reward = pad(taxi_reward[t], torch.full((N_STATES,), -1.0))
    wrong_drop = (f["passenger"] == IN_TAXI) & ~taxi_terminated[t][:, DROPOFF]  # not at dest.
    passenger[:, DROPOFF] = torch.where(wrong_drop, IN_TAXI, passenger[:, DROPOFF])
    reward[:, DROPOFF] = torch.where(wrong_drop, ILLEGAL_REWARD, reward[:, DROPOFF])
    dry = next_fuel == EMPTY
    reward = torch.where(dry, OUT_OF_FUEL_REWARD, reward)
    terminated = pad(taxi_terminated[t], torch.zeros(N_STATES, dtype=torch.bool)) | dry
    destination = f["destination"][:, None]
    nxt = ((loc * 5 + passenger) * 5 + destination) * FACTORS["fuel_level"] + next_fuel - EMPTY
    state = torch.arange(N_STATES)[:, None]
    next_state = torch.where(used[:, None], nxt, state)  # the unused code: stay (-1)
    reward = torch.where(used[:, None], reward, -1.0)
    terminated = terminated & used[:, None]
    start = (f["passenger"] < IN_TAXI) & used & (f["passenger"] != f["destination"])
    start &= (f["fuel"] >= START_FUEL[0]) & (f["fuel"] <= START_FUEL[1])
    return next_state, reward, terminated, start.nonzero().squeeze(1)


def reachable() -> torch.Tensor:
    """``[8750]`` bool: the states met in some episode (starts, their successors, end states)."""
    nxt, _, terminated, starts = transition_tables()
    live = torch.zeros(N_STATES, dtype=torch.bool)  # entered by a step that does not end
    live[starts] = True
    ends = torch.zeros_like(live)  # entered by the step that ends the episode
    frontier = live.clone()
    while bool(frontier.any()):
        go, stop = frontier[:, None] & ~terminated, frontier[:, None] & terminated
        ends[nxt[stop]] = True
        new = torch.zeros_like(live)
        new[nxt[go]] = True
        frontier = new & ~live
        live |= new
    return live | ends


class TaxiFuelTextEnv(TaxiFuelEnv):
    """Torch-batched taxi-fuel-earlier as the text sets it (see the module docstring).

    ``TaxiFuelEnv`` on this module's tables, observation fields and out-of-fuel rule.

    Args:
        seeds: one seed per learner.
        envs_per_learner: envs per learner ``E``.
        max_episode_steps: time limit (``None``: the text has none).
        device: where the state lives.
    """

    observation_sizes = {
        "observation": N_STATES,
        "taxi_row": 5,
        "taxi_col": 5,
        **FACTORS,
    }
    transition_tables = staticmethod(transition_tables)
    decode = staticmethod(decode)

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        max_episode_steps: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__(seeds, envs_per_learner, max_episode_steps, device)

    def _step_all(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        reward = self.reward_table[self.state, action]
        terminated = self.terminal_table[self.state, action]
        self.state = self.next_state[self.state, action]
        self.out_of_fuel = terminated & (self.state % FACTORS["fuel_level"] == 0)
        return reward, torch.ones_like(reward), terminated
