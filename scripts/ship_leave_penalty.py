"""Ship steering: the smallest out-of-square penalty that removes the incentive to leave.

With the text's rewards (-1 per step, +100 at the gate) an episode is worth ``-T + 100`` if the
ship passes the gate after ``T`` steps and ``-t`` if it leaves the square after ``t``; a penalty
``P`` for leaving removes the incentive everywhere iff ``P >= max_s (T(s) - t(s)) - 100``.
Estimated with near-shortest routes from uniform random starts: ``T`` from a proportional
controller steering at the gate's centre, ``t`` from one steering straight out through the
nearest side (docs/reproduction.md, "the -text variants").

    python scripts/ship_leave_penalty.py --starts 4000
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import torch

from agents.ship import bearing
from envs.ship import MAX_TURN, gate_crossed, out_of_bounds, ship_dynamics, wrap_degrees

GATE_CENTRE = torch.tensor([400.0, 400.0])
EDGE_HEADINGS = torch.tensor([0.0, 90.0, 180.0, -90.0])  # toward N, E, S, W


def sail(state: torch.Tensor, controller: Callable, limit: int) -> tuple[torch.Tensor, ...]:
    """Control steps (3 sampling intervals each) until gate or out: ``(gate, out, steps)``."""
    live = torch.ones(len(state), dtype=torch.bool)
    gate, out = torch.zeros_like(live), torch.zeros_like(live)
    steps = torch.zeros(len(state))
    for _ in range(limit):
        rate = controller(state)
        steps += live.float()
        for _ in range(3):
            nxt = ship_dynamics(state, rate)
            crossed = gate_crossed(state[:, :2], nxt[:, :2]) & live
            left = out_of_bounds(nxt[:, :2]) & live & ~crossed
            state = torch.where(live[:, None], nxt, state)
            gate, out = gate | crossed, out | left
            live &= ~(crossed | left)
        if not bool(live.any()):
            break
    return gate, out, steps


def to_gate(state: torch.Tensor) -> torch.Tensor:
    """Turn toward the gate's centre (bearing error in deg/s, clipped)."""
    aim = bearing(state[:, :2], GATE_CENTRE.expand(len(state), 2))
    return wrap_degrees(aim - state[:, 2]).clamp(-MAX_TURN, MAX_TURN)


def to_nearest_side(state: torch.Tensor) -> torch.Tensor:
    """Turn toward the nearest side of the square."""
    x, y = state[:, 0], state[:, 1]
    side = torch.stack([1000 - y, 1000 - x, y, x], 1).argmin(1)
    return wrap_degrees(EDGE_HEADINGS[side] - state[:, 2]).clamp(-MAX_TURN, MAX_TURN)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--starts", type=int, default=4000)
    parser.add_argument("--seed", type=int, default=0)
    a = parser.parse_args()
    torch.set_num_threads(1)
    g = torch.Generator().manual_seed(a.seed)
    u = torch.rand(a.starts, 4, generator=g)
    starts = torch.stack(
        [u[:, 0] * 1000, u[:, 1] * 1000, u[:, 2] * 360 - 180, (u[:, 3] * 2 - 1) * MAX_TURN], 1
    )
    gate, _, t_gate = sail(starts, to_gate, 900)
    _, out, t_out = sail(starts, to_nearest_side, 900)
    both = gate & out
    gain = (t_gate - t_out - 100)[both]
    worst = int(gain.argmax())
    print(
        f"controller through the gate: {gate.float().mean():.3f} of starts, "
        f"{t_gate[gate].mean():.0f} steps on average, at most {t_gate[gate].max():.0f}"
    )
    print(f"leaving pays (T - t > 100) from {(gain > 0).float().mean():.3f} of the starts")
    print(
        f"smallest penalty: max(T - t) - 100 = {gain.max():.0f} "
        f"(99th percentile {gain.quantile(0.99):.0f}); worst start "
        f"{[round(v, 1) for v in starts[both][worst].tolist()]}: "
        f"T {t_gate[both][worst]:.0f}, t {t_out[both][worst]:.0f}"
    )


if __name__ == "__main__":
    main()
