"""The references of the held-out tasks (issue 33, Build 6), fixed before any learner ran on them.

- ``heldout-couriers``: the exact optimum of the joint policy (value iteration over the joint
  MDP, mean over the uniform starts), the best policy of the hierarchy whose root choices see
  the joint state (equal to it: the hierarchy loses nothing) and two couriers that each run
  the optimal one-courier policy ignoring the other (what coordination is worth).
- ``heldout-polling``: the exact optimal gain of the SMDP (relative value iteration on
  Schweitzer's transformation), the best gain of the hierarchy Root -> Serve0, Serve1, Wait,
  and the exact gains of two one-line dispatch rules; ``--simulate`` also runs the exhaustive
  rule in the batched env and compares its measured reward rate with the exact gain.

    python scripts/heldout_references.py [--simulate]
"""

from __future__ import annotations

import argparse

import torch

from envs.heldout import couriers, polling


def courier_references() -> dict[str, float]:
    """Mean team return over the starts: optimum, hierarchy optimum, independent couriers."""
    _, _, starts = couriers.exact_model()
    best = couriers.optimal_values()
    return {
        "joint optimum": float(starts @ best),
        "hierarchy optimum (root sees the joint state)": float(
            starts @ couriers.hierarchy_values()
        ),
        "independent couriers (one-courier optimum each)": float(
            starts @ couriers.independent_values()
        ),
        "longest optimal episode": float(-best[starts > 0].min()),
    }


def polling_references() -> dict[str, float]:
    """Gains per unit of time: optimum, hierarchy optimum, the two rules (flat and as roots)."""
    P, r, tau = polling.exact_model()
    Ph, rh, th = polling.hierarchy_model()
    rules = {"exhaustive": polling.exhaustive_rule(), "priority (c-mu)": polling.priority_rule()}
    out = {"SMDP optimum": polling.gain(P, r, tau), "hierarchy optimum": polling.gain(Ph, rh, th)}
    for name, rule in rules.items():
        out[f"{name} rule"] = polling.gain(P, r, tau, rule)
        out[f"{name} rule, committed Serve_k"] = polling.gain(
            Ph, rh, th, polling.hierarchy_rule(rule)
        )
    return out


def simulate_rule(rule: torch.Tensor, rows: int = 256, steps: int = 4_000, burn_in: int = 200):
    """Reward per unit of time of the flat ``rule [S]`` in ``PollingEnv`` (mean, standard error)."""
    env = polling.PollingEnv([0], rows)
    td = env.reset()
    reward = torch.zeros(rows, dtype=torch.float64)
    time = torch.zeros(rows, dtype=torch.float64)
    for t in range(burn_in + steps):
        td = env.step(rule[td["state"]])
        if t >= burn_in:
            reward += td["reward"]
            time += td["duration"]
    rate = reward / time
    return float(rate.mean()), float(rate.std() / rows**0.5)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--simulate", action="store_true", help="check the env against the model")
    args = parser.parse_args()
    print("heldout-couriers (team return, mean over the 81 start pairs):")
    for name, value in courier_references().items():
        print(f"  {name}: {value:.4f}")
    print("heldout-polling (reward per unit of time):")
    for name, value in polling_references().items():
        print(f"  {name}: {value:.5f}")
    if args.simulate:
        mean, se = simulate_rule(polling.exhaustive_rule())
        print(f"  exhaustive rule simulated in PollingEnv: {mean:.4f} +- {se:.4f}")


if __name__ == "__main__":
    main()
