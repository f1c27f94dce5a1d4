"""Ship steering: how good are the learned low-level subtasks, against a simple controller?

Starts each low-level subtask alone at its local start (Figure 5.5) with a uniformly random
heading and turning rate, and runs it until local success, failure or the guard:

- the learned Gaussian policies of a saved hybrid (``<run>/<algo>.pt`` from
  ``scripts/fig_5_7_to_5_12_ship.py``), on their mean action;
- a proportional controller: turning rate = bearing error to the local goal, clipped to
  +-15 deg/s.

Prints the success rate per seed and, per band of the initial heading error, for seed 0 and for
the controller (docs/reproduction.md, "Why the low level is the bottleneck").

    python scripts/ship_low_level_check.py --run runs/ship --algo hybrid-earlier
    python scripts/ship_low_level_check.py --run runs/ship_text --algo hybrid --seeds 2
    python scripts/ship_low_level_check.py --run runs/ship_text --algo hybrid --seeds 2 \
        --file runs/ship_text/hybrid-pretrained.pt     # right after the pretraining
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import torch

from agents.ship import (
    LOCAL_GOAL,
    LOCAL_START,
    LOW_LEVEL_GUARD,
    SUBTASK_NAMES,
    bearing,
    local_failure,
    local_success,
    low_level_tile_coder,
    ship_hierarchy,
)
from agents.ship_learners import PARAMS, make_hybrid
from agents.ship_text import TEXT, make_hybrid_text, subtask_coder
from envs.ship import MAX_TURN, ship_dynamics, wrap_degrees
from hrl_torch.modules.policies import squash

BANDS = ((0, 45), (45, 90), (90, 135), (135, 181))
SAMPLES_PER_CONTROL = 3  # a control step is 3 sampling intervals (0.6 s)


def run(subtask: int, controller: Callable, n: int, seed: int) -> tuple[torch.Tensor, ...]:
    """Outcomes ``[n]`` (1 success, 2 failure, 0 guard), initial heading errors and steps."""
    g = torch.Generator().manual_seed(seed)
    state = torch.zeros(n, 4)
    state[:, :2] = LOCAL_START[subtask]
    state[:, 2] = torch.rand(n, generator=g) * 360 - 180
    state[:, 3] = (torch.rand(n, generator=g) * 2 - 1) * MAX_TURN
    goal = LOCAL_GOAL[subtask].expand(n, 2)
    error = wrap_degrees(state[:, 2] - bearing(state[:, :2], goal)).abs()
    kind = torch.full((n,), subtask)
    live = torch.ones(n, dtype=torch.bool)
    outcome = torch.zeros(n, dtype=torch.long)
    steps = torch.zeros(n)
    for _ in range(LOW_LEVEL_GUARD):
        rate = controller(state, goal)
        for _ in range(SAMPLES_PER_CONTROL):
            state = torch.where(live[:, None], ship_dynamics(state, rate), state)
        steps += live.float()
        ok = local_success(state, kind) & live
        bad = local_failure(state) & ~ok & live
        outcome[ok], outcome[bad] = 1, 2
        live &= ~(ok | bad)
    return outcome, error, steps


def proportional(state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
    """Turn toward the goal: the bearing error in deg/s, clipped to the turning range."""
    return wrap_degrees(bearing(state[:, :2], goal) - state[:, 2]).clamp(-MAX_TURN, MAX_TURN)


def learned(theta: torch.Tensor, coder) -> Callable:
    """The Gaussian policy's mean action (the tile average, squashed into the turning range)."""
    return lambda state, goal: squash(theta[coder(state)].mean(-1), -MAX_TURN, MAX_TURN)


def band_rates(outcome, error, steps) -> list[float]:
    """Success per band of start heading error (``BANDS``)."""
    rates = []
    for lo, hi in BANDS:
        band = (error >= lo) & (error < hi)
        rates.append((outcome[band] == 1).float().mean().item())
    return rates


def report(label: str, outcome, error, steps) -> None:
    print(f"  {label}: success {(outcome == 1).float().mean():.3f}")
    for lo, hi in BANDS:
        band = (error >= lo) & (error < hi)
        ok = band & (outcome == 1)
        print(
            f"    heading error {lo:3d}-{min(hi, 180):3d} deg: success "
            f"{(outcome[band] == 1).float().mean():.2f}, steps when successful "
            f"{steps[ok].mean():.0f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", default="runs/ship", help="folder holding hybrid.pt")
    parser.add_argument("--seeds", type=int, default=5, help="learners in the saved hybrid")
    parser.add_argument("--starts", type=int, default=20_000)
    parser.add_argument("--algo", default="hybrid", choices=["hybrid", "hybrid-earlier"])
    parser.add_argument("--file", default=None, help="checkpoint (default: <run>/<algo>.pt)")
    a = parser.parse_args()
    coders = [low_level_tile_coder()] * 2
    if a.algo == "hybrid-earlier":
        learner = make_hybrid(ship_hierarchy(PARAMS.out_of_bounds_reward), a.seeds, PARAMS)
    else:
        saved = Path(a.run) / f"{a.algo}.json"  # the run's TextParams (features, ...)
        params = TEXT
        if saved.exists():
            params = replace(TEXT, **json.loads(saved.read_text())["params"])
        learner = make_hybrid_text(ship_hierarchy(params.out_of_bounds_reward), a.seeds, params)
        coders = [subtask_coder(k, params) for k in range(2)]
    state = torch.load(a.file or f"{a.run}/{a.algo}.pt", weights_only=True)
    for key, value in learner.state_dict().items():  # runs saved before these buffers
        if key.endswith(("reward_to_go_mean", "value_table")):
            state.setdefault(key, torch.zeros_like(value))
    learner.load_state_dict(state)
    for subtask, name in enumerate(SUBTASK_NAMES):
        coder = coders[subtask]
        print(name)
        rates, worst = [], []
        for p in range(a.seeds):
            policy = learned(learner.pg.group_view(name, p), coder)
            result = run(subtask, policy, a.starts, seed=p)
            rates.append(round((result[0] == 1).float().mean().item(), 3))
            worst.append(round(min(band_rates(*result)), 3))
            if p == 0:
                report("learned, seed 0", *result)
        print(f"  learned, success per seed: {rates}")
        print(f"  learned, worst heading band per seed: {worst}")
        report("proportional controller", *run(subtask, proportional, a.starts, seed=0))


if __name__ == "__main__":
    main()
