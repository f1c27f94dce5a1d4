"""A grid of configurations x seeds: one population against separate runs, in one process run.

Three routes train the same configurations, each with the same seeds and budget:

(a) ``population``: the whole grid x seeds as one population (``train_grid``, one process);
(b) ``sequential``: each configuration as its own run of its seeds (``train_grid`` of one
    configuration, one after another in this process: what a Ray trial trains, without Ray);
(c) ``ray``: ``hrl_torch.runs.sweep.run_sweep`` (a local Ray with this machine's CPUs, one trial
    per configuration, each an ordinary run folder), when Ray imports.

Grids: ``alpha x epsilon`` (``learner.alpha`` x ``exploration.epsilon.end``, routes a and b;
measured before the Ray route could set exploration values, and kept so) and ``alpha`` (as
many ``learner.alpha`` values, all three routes). Wall seconds from the call to its return
(building, training, the final evaluation; Ray: its start, the run folders and its shutdown
too). CPU seconds of this process are printed beside (Ray's workers are other processes).
The machines are shared: compare only ratios taken in one run.

    PYTHONPATH=$PWD python benchmarks/bench_population_grid.py [--ray] [--steps N] [--out F]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.runs import registry
from hrl_torch.runs.population_grid import train_grid
from hrl_torch.runs.sweep import configurations

ALPHAS = [0.1, 0.2, 0.3, 0.5]
ENDS = [0.01, 0.1]
ALPHAS_8 = [0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.7, 0.9]


def timed(fn):
    """``(wall seconds, process CPU seconds, fn())``."""
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - wall, time.process_time() - cpu, out


def local(args, grid: dict) -> dict:
    """Routes a and b on ``grid`` (the configurations share ``args``' budget)."""
    fixed = {"steps": args.steps, "eval_every": 0, "envs_per_learner": args.envs}
    configs = [{**fixed, **c} for c in configurations(grid)]
    seeds = list(range(args.seeds))
    taxi = registry.get(args.domain)
    pop = timed(lambda: train_grid(taxi, args.algo, configs, seeds, device=args.device))
    seq = timed(
        lambda: [train_grid(taxi, args.algo, [c], seeds, device=args.device) for c in configs]
    )
    same = pop[2][1].final_eval == [r for _, res in seq[2] for r in res.final_eval]
    return {
        "configs": len(configs),
        "population_wall": pop[0],
        "population_cpu": pop[1],
        "sequential_wall": seq[0],
        "sequential_cpu": seq[1],
        "sequential_over_population": seq[0] / pop[0],
        "final_eval_equal": same,
    }


def ray_route(args, grid: dict) -> dict:
    """Route c: ``run_sweep`` into a temporary folder."""
    from hrl_torch.runs.sweep import run_sweep

    grid = {**grid, "envs_per_learner": [args.envs], "eval_every": [0]}
    with tempfile.TemporaryDirectory() as out:
        wall, cpu, rows = timed(
            lambda: run_sweep(args.domain, args.algo, grid, args.seeds, out=out, steps=args.steps)
        )
    return {
        "ray_wall": wall,
        "ray_cpu": cpu,
        "ray_finished": sum(r["status"] == "finished" for r in rows),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--domain", default="taxi")
    p.add_argument("--algo", default="maxq-q")
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--steps", type=int, default=15_360, help="env steps per learner")
    p.add_argument("--envs", type=int, default=64, help="envs per learner")
    p.add_argument("--device", default="cpu")
    p.add_argument("--ray", action="store_true", help="also the Ray route (needs ray[tune])")
    p.add_argument("--out", default=None, help="write the numbers as JSON here")
    p.add_argument("--alpha-only", action="store_true", help="skip the alpha x epsilon grid")
    args = p.parse_args()
    torch.set_num_threads(1)
    os.environ.setdefault("RL_LOGGING_LEVEL", "WARNING")
    found = {"args": vars(args), "cpus": os.cpu_count(), "torch": torch.__version__}
    if not args.alpha_only:
        found["alpha_x_epsilon"] = local(
            args, {"learner.alpha": ALPHAS, "exploration.epsilon.end": ENDS}
        )
        print(json.dumps(found["alpha_x_epsilon"]), flush=True)
    found["alpha"] = local(args, {"learner.alpha": ALPHAS_8})
    print(json.dumps(found["alpha"]), flush=True)
    if args.ray:
        found["alpha"].update(ray_route(args, {"alpha": ALPHAS_8}))
        a = found["alpha"]
        a["ray_over_population"] = a["ray_wall"] / a["population_wall"]
        print(json.dumps(a), flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(found, f, indent=2)


if __name__ == "__main__":
    main()
