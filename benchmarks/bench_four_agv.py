"""Four-AGV scheduling: the batched env against its PettingZoo AEC form, and table memory.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_four_agv.py [--seconds 10]

1. Env steps (decision epochs x env rows) per second with random actions, in one run: the
   batched ``FourAGVEnv`` at 5 seeds x 64 envs (4 AGVs each) and one row wrapped as a PettingZoo
   ``AECEnv`` (``hrl_torch.pettingzoo_env``) stepped in plain Python, agent by agent.
2. The tables of every learning algorithm of the ``four-agv`` domain for 5 seeds: megabytes of
   their banks (float32 entries) and of the update scratch buffers.

Prints markdown tables and the load average.
"""

from __future__ import annotations

import argparse
import os
import time

import torch

import agents  # noqa: F401  (registers the domains)
from benchmarks.plain_pettingzoo import steps_per_second
from envs.four_agv import N_ACTIONS, FourAGVEnv
from hrl_torch import registry
from hrl_torch.multiagent import MultiAgentConfig
from hrl_torch.pettingzoo_env import make_aec
from hrl_torch.tables import TableBank


def batched_steps_per_second(seeds: int, envs: int, seconds: float) -> float:
    """Env-row decision epochs per second of the batched env with random actions."""
    env = FourAGVEnv(list(range(seeds)), envs)
    env.reset()
    g = torch.Generator().manual_seed(0)
    actions = torch.randint(0, N_ACTIONS, (256, env.batch_size, env.n_agents), generator=g)
    for k in range(20):
        env.step(actions[k])
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        env.step(actions[steps % 256])
        steps += 1
    return steps * env.batch_size / (time.perf_counter() - start)


def table_megabytes(seeds: int) -> list[tuple[str, float, float]]:
    """``(algorithm, table MB, scratch MB)`` of every learning algorithm of ``four-agv``."""
    domain = registry.get("four-agv")
    out = []
    for name, spec in sorted(domain.algos.items()):
        if name in ("fcfs", "hqf", "nsf"):
            continue
        n_agents = spec.env_options.get("n_agents", 4)
        sets = (spec.multiagent or MultiAgentConfig()).table_sets(seeds, n_agents)
        learner = spec.make_learner(spec.make_graph(), sets)
        banks = [m for m in learner.modules() if isinstance(m, TableBank)]
        tables = sum(b.store.numel() for b in banks) * 4 / 2**20
        scratch = sum(
            2 * b.store.numel() * 4 for b in banks if b.store.numel() <= b.SCRATCH_LIMIT
        )
        out.append((name, tables, scratch / 2**20))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"load average at start: {os.getloadavg()}")
    batched = batched_steps_per_second(5, 64, args.seconds)
    plain = steps_per_second(lambda: make_aec(FourAGVEnv, seed=0), n_steps=3_000)
    print("| path | env rows | env steps/s | vs plain |")
    print("|---|---:|---:|---:|")
    print(f"| PettingZoo AEC, plain Python | 1 | {plain:,.0f} | 1.0x |")
    print(f"| batched FourAGVEnv | 5 x 64 | {batched:,.0f} | {batched / plain:,.1f}x |")
    print()
    print("| algorithm (5 seeds) | tables MB | update scratch MB |")
    print("|---|---:|---:|")
    for name, tables, scratch in table_megabytes(5):
        print(f"| {name} | {tables:,.1f} | {scratch:,.1f} |")
    print(f"load average at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
