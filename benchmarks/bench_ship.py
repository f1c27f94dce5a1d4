"""Ship steering hybrid: env steps/s of the Trainer on the TorchRL collector path and direct.

    .venv/bin/python benchmarks/bench_ship.py [--seconds 30] [--envs 1024] [--online]

Both paths (``Trainer(collector=True)`` and the direct loop) train the same population (5
seeds, the ``hybrid`` AlgoSpec of ``agents.ship``) from a fresh learner; each is warmed up for
100 batched steps, then timed for ``--seconds``. Env steps count every row of every batched
step (auto-reset steps included), as the trainer does. Prints a markdown table; the load
average is printed so a busy machine is visible.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import torch

from agents.ship import ship_hierarchy
from agents.ship_domain import DOMAIN_EARLIER as DOMAIN  # the reading this benchmark times
from agents.ship_learners import PARAMS, make_hybrid
from envs.ship import ShipSteeringEnv
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer


def _learner(seeds, online=False):
    graph = ship_hierarchy(PARAMS.out_of_bounds_reward)
    return graph, make_hybrid(graph, len(seeds), replace(PARAMS, online=online))


def bench(seeds, envs, seconds, online=False, collector=False):
    """Env steps/s of the Trainer on the direct loop or on the TorchRL collector path."""
    spec = DOMAIN.algos["hybrid"]
    graph, learner = _learner(seeds, online)
    env = ShipSteeringEnv(seeds, envs)
    config = TrainConfig(steps=10**12, eval_every=0, progress=False, success_key="success")
    trainer = Trainer(
        env,
        graph,
        learner,
        spec.make_exploration(config),
        config,
        None,
        spec.executor,
        collector=collector,
    )
    for _ in range(100):
        trainer.train_step()
    start, t0 = trainer.step, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        trainer.train_step()
    rate = (trainer.step - start) * len(seeds) / (time.perf_counter() - t0)
    trainer.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--envs", type=int, nargs="+", default=[1024])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument(
        "--online", action="store_true", help="also time HPGRL's per-step updates (line 16)"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    seeds = list(range(args.seeds))
    print(f"load average at start: {os.getloadavg()}")
    print("| path | HPGRL updates | learners x envs | env steps/s | ms per batched step |")
    print("|---|---|---:|---:|---:|")
    modes = [False, True] if args.online else [False]
    for envs in args.envs:
        for online in modes:
            for name, collector in (("collector", True), ("direct loop", False)):
                rate = bench(seeds, envs, args.seconds, online, collector)
                ms = 1000 * len(seeds) * envs / rate
                mode = "every step" if online else "at the renewal"
                print(
                    f"| {name} | {mode} | {len(seeds)} x {envs} | {rate:,.0f} | {ms:.1f} |",
                    flush=True,
                )
    print(f"load average at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
