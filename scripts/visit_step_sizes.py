"""Constant step sizes against per-entry visit-count ones on the registered tasks (issue 33).

For each registered ``domain algo`` pair asked for, one population run of ``--seeds`` seeds
with the registered configuration untouched, and one per ``--lows`` value with only its step
size replaced by ``VisitCount(low)`` (``alpha_n = max(1 / n, low)`` per table entry). Each row:
the registered budget (``--budget-scale`` scales it), the greedy evaluation at the end (mean
and per seed), and, where the algorithm has a threshold, the steps to it per seed.

    python scripts/visit_step_sizes.py taxi:maxq-q taxi:smdp-q trash:selfish --lows 0.2
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.modules.schedules import VisitCount
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer


def run(domain: str, algo: str, seeds: int, low: float | None, scale: float) -> dict:
    """One population run; ``low`` None: the registered step size."""
    dom = registry.get(domain)
    spec = dom.algos[algo]
    learner = spec.learner if low is None else spec.learner.with_argument("alpha", VisitCount(low))
    steps = int(spec.train.steps * scale)
    every = spec.train.eval_every and max(steps // 16, 1)
    train = replace(spec.train, steps=steps, eval_every=every, progress=False)
    dom = replace(dom, algos={algo: replace(spec, learner=learner, train=train)})
    opts = RunOptions(seeds=list(range(seeds)), progress=False, tensorboard=False)
    start = time.perf_counter()
    result = build_trainer(dom, algo, opts).train()
    final = [round(float(v), 3) for v in result.final_eval]
    hits = result.steps_to_threshold if spec.train.threshold is not None else None
    return {
        "task": f"{domain} {algo}",
        "alpha": spec.learner.arguments(2).get("alpha") if low is None else f"VisitCount({low})",
        "steps": steps,
        "final": final,
        "mean": round(statistics.mean(final), 3),
        "sd": round(statistics.stdev(final), 3) if len(final) > 1 else 0.0,
        "hits": None if hits is None else ["-" if h is None else h for h in hits],
        "seconds": round(time.perf_counter() - start, 1),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("tasks", nargs="+", help="domain:algo pairs")
    p.add_argument("--lows", type=float, nargs="+", default=[0.2])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--budget-scale", type=float, default=1.0)
    args = p.parse_args()
    torch.set_num_threads(1)
    for task in args.tasks:
        domain, algo = task.split(":")
        for low in [None, *args.lows]:
            print(run(domain, algo, args.seeds, low, args.budget_scale), flush=True)


if __name__ == "__main__":
    main()
