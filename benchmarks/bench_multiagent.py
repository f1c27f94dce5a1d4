"""Multi-agent domains (four AGVs, two taxis): batched env vs its PettingZoo AEC form; tables.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_multiagent.py [--seconds 10]

1. Env steps (decision epochs x env rows) per second with random actions, in one run: the
   batched env (``FourAGVEnv``, ``TwoTaxiEnv``) at 5 seeds x 64 envs and one row wrapped as a
   PettingZoo ``AECEnv`` (``hrl_torch.env.pettingzoo_env``) stepped in plain Python, agent by agent.
2. The tables of every learning algorithm of the ``four-agv-earlier`` and ``two-taxi-earlier``
domains for 5
   seeds: megabytes of their banks (float32 entries) and of the update scratch buffers.

Prints markdown tables and the load average.
"""

from __future__ import annotations

import argparse
import os
import time

import torch

import agents  # noqa: F401  (registers the domains)
from benchmarks.plain_pettingzoo import steps_per_second
from envs.four_agv import FourAGVEnv
from envs.two_taxi import TwoTaxiEnv
from hrl_torch.env.pettingzoo_env import make_aec
from hrl_torch.modules.tables import TableBank
from hrl_torch.multiagent.cooperative import MultiAgentConfig
from hrl_torch.runs import registry

ENVS = {"four-agv-earlier": FourAGVEnv, "two-taxi-earlier": TwoTaxiEnv}


def batched_steps_per_second(env_class, seeds: int, envs: int, seconds: float) -> float:
    """Env-row decision epochs per second of the batched env with random actions."""
    env = env_class(list(range(seeds)), envs)
    env.reset()
    g = torch.Generator().manual_seed(0)
    actions = torch.randint(0, env.n_actions, (256, env.batch_size, env.n_agents), generator=g)
    for k in range(20):
        env.step(actions[k])
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        env.step(actions[steps % 256])
        steps += 1
    return steps * env.batch_size / (time.perf_counter() - start)


def table_megabytes(domain_name: str, seeds: int) -> list[tuple[str, float, float]]:
    """``(algorithm, table MB, scratch MB)`` of every learning algorithm of a domain."""
    domain = registry.get(domain_name)
    default_agents = ENVS[domain_name]([0], 1).n_agents
    out = []
    for name, spec in sorted(domain.algos.items()):
        if name in ("fcfs", "hqf", "nsf"):
            continue
        n_agents = spec.env_options.get("n_agents", default_agents)
        sets = (spec.multiagent or MultiAgentConfig()).table_sets(seeds, n_agents)
        learner = spec.make_learner(spec.make_graph(), sets)
        banks = [m for m in learner.modules() if isinstance(m, TableBank)]
        tables = sum(b.store.numel() for b in banks) * 4 / 2**20
        scratch = sum(2 * b.store.numel() * 4 for b in banks if b.store.numel() <= b.SCRATCH_LIMIT)
        out.append((name, tables, scratch / 2**20))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"load average at start: {os.getloadavg()}")
    print("| domain | path | env rows | env steps/s | vs plain |")
    print("|---|---|---:|---:|---:|")
    for name, env_class in ENVS.items():
        batched = batched_steps_per_second(env_class, 5, 64, args.seconds)
        plain = steps_per_second(lambda env_class=env_class: make_aec(env_class, seed=0), 3_000)
        print(f"| {name} | PettingZoo AEC, plain Python | 1 | {plain:,.0f} | 1.0x |")
        print(f"| {name} | batched | 5 x 64 | {batched:,.0f} | {batched / plain:,.1f}x |")
    print()
    print("| domain | algorithm (5 seeds) | tables MB | update scratch MB |")
    print("|---|---|---:|---:|")
    for domain in ENVS:
        for name, tables, scratch in table_megabytes(domain, 5):
            print(f"| {domain} | {name} | {tables:,.1f} | {scratch:,.1f} |")
    print(f"load average at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
