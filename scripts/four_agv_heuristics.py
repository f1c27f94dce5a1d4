"""Throughput of the AGV dispatching rules of Figure 6.7 on the four-AGV task (Section 6.4).

Runs first come first serve, highest queue first and nearest station first (``agents/four_agv``)
on ``FourAGVEnv`` (Table 6.1 timing, or 2 s primitives with ``--slow`` as in Figure 6.5) for a
fixed simulated time and prints the assemblies delivered per 1,000 s: mean and standard
deviation over the seeds, each seed averaged over its envs. The three rules run as one batch of
env rows, rule ``k`` on block ``k``, with the same seeds in every block: every rule meets the
same part arrivals and assembly times (the env draws its random numbers whatever the state).
``--per-agv`` runs the per-AGV rules of ``four-agv`` (each vehicle on its own view,
committed to its job, no reservations) instead of the centralised dispatchers.
Assemblies count when they are unloaded before the time limit; every row runs until its clock
passes it.

    python scripts/four_agv_heuristics.py [--seeds 5] [--envs 16] [--agents 4] [--time 20000]
        [--slow] [--per-agv]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from agents.four_agv_rules import DISPATCH_RULES
from agents.four_agv_text import PerAGVRule
from envs.four_agv import FIGURE_6_5, TABLE_6_1, FourAGVEnv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--envs", type=int, default=16, help="envs per seed")
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--time", type=float, default=20_000.0, help="simulated seconds")
    parser.add_argument("--capacity", type=int, default=3)
    parser.add_argument("--slow", action="store_true", help="2 s primitives (Figure 6.5)")
    parser.add_argument(
        "--per-agv",
        action="store_true",
        help="each AGV applies the rule on its own, committed, no reservations (four-agv)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)

    names = list(DISPATCH_RULES)
    seeds = list(range(args.seeds))
    env = FourAGVEnv(
        seeds * len(names),
        args.envs,
        n_agents=args.agents,
        capacity=args.capacity,
        timing=FIGURE_6_5 if args.slow else TABLE_6_1,
    )
    block = args.seeds * args.envs  # env rows per rule
    if args.per_agv:
        rules = [PerAGVRule(name, block, args.agents, args.capacity) for name in names]
    else:
        rules = [DISPATCH_RULES[name](block, args.agents, capacity=args.capacity) for name in names]
    b, n = env.batch_size, env.n_agents
    clock = torch.zeros(b, dtype=torch.float64)
    delivered = torch.zeros(b, dtype=torch.float64)
    td = env.reset()
    steps, start = 0, time.perf_counter()
    while float(clock.min()) < args.time:
        rows = env.agent_rows(td)
        action = torch.cat(
            [rule(rows[k * block * n : (k + 1) * block * n]) for k, rule in enumerate(rules)]
        )
        td = env.step(action.view(b, n))
        # an unload delivers at its decision epoch: the clock before the step
        delivered += torch.where(clock < args.time, td["assemblies_delivered"].double(), 0.0)
        clock += td["duration"].double()
        steps += 1
    wall = time.perf_counter() - start

    timing = "2 s primitives (Figure 6.5)" if args.slow else "Table 6.1"
    print(
        f"four-AGV dispatching rules: {args.agents} AGVs, capacity {args.capacity}, {timing}, "
        f"{args.time:,.0f} s simulated, {args.seeds} seeds x {args.envs} envs"
    )
    print(f"({steps:,} decision epochs in {wall:.0f} s of wall-clock)\n")
    print(f"{'rule':<28} {'assemblies / 1,000 s':>22}   per seed")
    per_row = (delivered / args.time * 1_000).view(len(names), args.seeds, args.envs)
    for rule, values in zip(rules, per_row, strict=True):
        per_seed = values.mean(-1).tolist()
        mean, sd = statistics.mean(per_seed), statistics.stdev(per_seed) if args.seeds > 1 else 0
        cells = " ".join(f"{v:6.1f}" for v in per_seed)
        print(f"{rule.name:<28} {mean:>14.1f} +- {sd:<5.1f}   {cells}")


if __name__ == "__main__":
    main()
