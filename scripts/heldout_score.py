"""Score held-out runs against their references (issue 33, Build 6; docs/heldout.md).

For each run folder: per seed, the share of the reference its final greedy evaluation reached
and whether any greedy episode ran into the step limit. ``heldout-couriers``: the share is the
optimal mean return over the evaluation's own start states divided by the seed's mean return
(costs: 1.0 is optimal); ``heldout-polling``: the seed's greedy reward per unit of time
divided by the exact optimal gain. The verdict: >= 95% in >= 4 of 5 seeds and no episode at
the step limit.

    python scripts/heldout_score.py runs/heldout-couriers__cooperative__<time> ...
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import torch

from envs.heldout import couriers, polling
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import evaluate_run
from hrl_torch.training.runlog import read_episodes


def courier_shares(run: Path) -> tuple[list[float], list[int], list[float]]:
    """Per seed: share of the optimum, episodes at the step limit, mean return."""
    best = couriers.optimal_values()
    by_seed: dict[int, list[dict]] = {}
    for r in read_episodes(run):
        by_seed.setdefault(r["seed"], []).append(r)
    shares, limits, means = [], [], []
    for seed in sorted(by_seed):
        rows = by_seed[seed]
        optimum = []
        for r in rows:
            pos = [int(x) for x in re.search(r"agents\.pos=(\d+),(\d+)", r["start"]).groups()]
            parcels = int(re.search(r"parcels=(\d+)", r["start"]).group(1))
            optimum.append(float(best[couriers.encode(torch.tensor(pos), parcels)]))
        mean = sum(r["return"] for r in rows) / len(rows)
        shares.append(sum(optimum) / len(rows) / mean)
        limits.append(sum(r["truncated"] for r in rows))
        means.append(mean)
    return shares, limits, means


def polling_shares(run: Path) -> tuple[list[float], list[int], list[float]]:
    """Per seed: share of the optimal gain, (no episodes: 0), the greedy policy's exact gain.

    The greedy policy is read from the checkpoint: its first action in each of the 50 states
    (the subtasks below the root have one choice each, so the first action names the root's
    choice: Process here, Switch to serve the other queue, Wait), then evaluated exactly on
    the hierarchy's SMDP (``polling.hierarchy_model``; a flat learner's on the flat SMDP).
    The run's simulated greedy throughput is printed beside it.
    """
    optimum = polling.gain(*polling.exact_model())
    trainer, _ = evaluate_run(run)
    env = polling.PollingEnv(trainer.env.seeds, polling.N_STATES)
    env.reset()
    where, q0, q1 = polling.states()
    env.where = where.repeat(trainer.P)
    env.queue = torch.stack([q0, q1], 1).repeat(trainer.P, 1)
    zero = torch.zeros(env.batch_size)
    obs = env._output(zero, zero, zero.bool(), zero.bool(), zero.bool())
    action = trainer.evaluation_agent(env, "score").start(obs).view(trainer.P, -1)
    if "Serve0" in trainer.graph.names:  # the hierarchy
        model = polling.hierarchy_model()
        gains = [polling.gain(*model, polling.hierarchy_rule(a)) for a in action]
    else:  # a flat learner: its actions are the policy
        model = polling.exact_model()
        gains = [polling.gain(*model, a) for a in action]
    summary = json.loads((run / "summary.json").read_text())
    simulated = [round(s["final_eval_throughput"], 4) for s in summary["per_seed"]]
    print(f"  (simulated greedy throughput per seed: {simulated})")
    return [g / optimum for g in gains], [0] * len(gains), gains


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    args = parser.parse_args()
    registry.load_module("agents.heldout")
    for run in args.runs:
        domain = json.loads((run / "summary.json").read_text())
        score = courier_shares if domain["domain"] == "heldout-couriers" else polling_shares
        shares, limits, values = score(run)
        reached = sum(s >= 0.95 for s in shares)
        ok = reached >= 4 and not any(limits)
        print(
            f"{domain['domain']} {domain['algo']}: values {[round(v, 4) for v in values]}; "
            f"share {[round(s, 4) for s in shares]}; >= 95% in {reached} of {len(shares)}; "
            f"step-limit episodes {limits}; {'met' if ok else 'missed'}"
        )


if __name__ == "__main__":
    main()
