"""One changed setting on a held-out task (issue 33, Build 6: diagnosing a default that failed).

Not a default: each variant replaces one thing of the registered spec and writes a normal run
folder (score it with ``scripts/heldout_score.py``). ``--visits LOW HIGH`` gives every table
entry the step size ``clip(1 / n, LOW, HIGH)`` (``hrl_torch.modules.schedules.VisitCount``);
``--steps`` changes the budget (the exploration schedule follows it); ``--smdp-q`` swaps
MAXQ-Q for SMDP Q-learning with the same settings (each subtask learns ``Q(i, s, a)`` whole,
no ``V(child) + C`` decomposition). ``--domain`` may name a
registered domain too (e.g. ``two-robots`` with ``--module hrl_two_robots``), to try the same
change on a task the defaults were tuned on.

    python scripts/heldout_variants.py heldout-couriers cooperative --visits 0.05 1.0
"""

from __future__ import annotations

import argparse
import dataclasses

import torch

from hrl_torch.common.config import Make
from hrl_torch.learners import SMDPQLearner
from hrl_torch.modules.schedules import VisitCount
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, run_experiment


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("domain")
    parser.add_argument("algo")
    parser.add_argument("--module", default="agents.heldout", help="the domain's module")
    parser.add_argument("--visits", nargs=2, type=float, metavar=("LOW", "HIGH"))
    parser.add_argument("--steps", type=int)
    parser.add_argument(
        "--smdp-q", action="store_true", help="SMDP Q-learning (no value decomposition) instead"
    )
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--out", default="runs")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.module:
        registry.load_module(args.module)
    domain = registry.get(args.domain)
    spec = domain.algos[args.algo]
    if args.visits:
        spec = dataclasses.replace(
            spec, learner=spec.learner.with_argument("alpha", VisitCount(*args.visits))
        )
    if args.smdp_q:  # the same settings, Q(i, s, a) learned whole at every subtask
        spec = dataclasses.replace(spec, learner=Make(SMDPQLearner, **spec.learner.kwargs))
    domain = dataclasses.replace(domain, algos={**domain.algos, args.algo: spec})
    opts = RunOptions(seeds=list(range(args.seeds)), steps=args.steps, out=args.out)
    opts.progress, opts.tensorboard = False, False
    run_dir, _ = run_experiment(domain, args.algo, opts)
    print(run_dir)


if __name__ == "__main__":
    main()
