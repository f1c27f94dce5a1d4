"""One measured change at a time on ``four-agv`` (issue 33): train, then greedy throughput.

Trains a registered learner of ``four-agv`` (``--algo``) with its step size, discount or
budget changed as asked, then measures its greedy throughput (assemblies per 1,000 s) in a
window ``[--burn-in, --burn-in + --window)`` s of a fresh system, ``--rows`` rows per seed; the
per-AGV rules (``--rules``) run in the same window on the same seeds for the reference. Prints
one line per run: what, seeds, budget, throughput (mean, per seed) and wall time.

    python scripts/four_agv_text_variants.py --algo selfish --seeds 2 --alpha visits:0.2 \\
        --gamma 0.8 --rules nsf
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import torch
from four_agv_where_time_goes import trainer_time_shares

import agents  # noqa: F401  (registers the domains)
from agents.four_agv import GAMMA
from agents.four_agv_text import assemblies, text_hierarchy
from hrl_torch.modules.schedules import VisitCount
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.continuing import ThroughputEvaluator


def _alpha(text: str):
    """``0.2`` or ``visits:LOW`` (``VisitCount(LOW)``)."""
    if text.startswith("visits:"):
        return VisitCount(float(text.split(":", 1)[1]))
    return float(text)


def run(args, algo: str, learn: bool) -> dict:
    """One population run of ``algo`` (a learner with the asked changes, or a rule)."""
    dom = registry.get("four-agv")
    spec = dom.algos[algo]
    steps = args.steps if learn else 1
    learner = spec.learner
    levels = 2 if args.small_root else 3
    if args.small_root or args.root_idle:  # (selfish/single: the plain text graph changed)
        spec = replace(
            spec, make_graph=lambda: text_hierarchy(root_levels=levels, root_idle=args.root_idle)
        )
    if args.own_rewards:
        spec = replace(spec, env_options={**spec.env_options, "own_rewards": True})
    if args.part_reward:
        spec = replace(spec, env_options={**spec.env_options, "part_reward": args.part_reward})
    if learn:
        learner = learner.with_argument("alpha", _alpha(args.alpha))
        learner = learner.with_argument("gamma", args.gamma)
    train = replace(spec.train, steps=steps, eval_every=0, eval_episodes=args.rows, progress=False)
    window = ThroughputEvaluator(
        horizon_time=args.window,
        burn_in_time=args.burn_in,
        max_steps=args.max_steps,
        metric=assemblies,
        scale=1_000.0,
        unit="assemblies per 1,000 s",
    )
    dom = replace(
        dom,
        algos={algo: replace(spec, learner=learner, train=train)},
        make_evaluator=lambda config: window,
    )
    opts = RunOptions(seeds=list(range(args.seeds)), progress=False, tensorboard=False)
    start = time.perf_counter()
    trainer = build_trainer(dom, algo, opts)
    result = trainer.train()
    greedy = [round(float(v), 1) for v in result.final_eval]
    seconds = round(time.perf_counter() - start, 1)
    if args.where:  # where the greedy policies' time goes, in the same window
        print(trainer_time_shares(trainer), flush=True)
    what = f"{algo} alpha {args.alpha} gamma {args.gamma}" if learn else f"rule {algo}"
    what += ", own rewards" if args.own_rewards else ""
    what += ", 256-state root" if args.small_root else ""
    what += ", Idle at the root" if args.root_idle else ""
    what += f", part reward {args.part_reward:g}" if args.part_reward else ""
    return {
        "what": what,
        "seeds": args.seeds,
        "budget": steps,
        "greedy": round(statistics.mean(greedy), 1),
        "per_seed": greedy,
        "window": f"[{args.burn_in:g}, {args.burn_in + args.window:g}) s x {args.rows} rows",
        "seconds": seconds,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--algo", nargs="*", default=["selfish"], help="learners ('' for none)")
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--steps", type=int, default=200_000, help="decision epochs per seed")
    p.add_argument("--alpha", default="0.2", help="a number or visits:LOW")
    p.add_argument("--gamma", type=float, default=GAMMA, help="discount per second")
    p.add_argument("--burn-in", type=float, default=100.0)
    p.add_argument("--window", type=float, default=400.0)
    p.add_argument("--rows", type=int, default=2, help="greedy rows per seed")
    p.add_argument("--max-steps", type=int, default=40_000)
    p.add_argument("--small-root", action="store_true", help="root: Pi empty / not (256)")
    p.add_argument("--own-rewards", action="store_true", help="each AGV paid for its own")
    p.add_argument("--root-idle", action="store_true", help="Idle at the root (no commitment)")
    p.add_argument("--part-reward", type=float, default=0.0, help="reward per part into Di")
    p.add_argument("--where", action="store_true", help="also print where the time goes")
    p.add_argument("--rules", nargs="*", default=[], help="per-AGV rules in the same window")
    args = p.parse_args()
    torch.set_num_threads(1)
    for rule in args.rules:
        print(run(args, rule, learn=False), flush=True)
    for algo in args.algo:
        print(run(args, algo, learn=True), flush=True)


if __name__ == "__main__":
    main()
