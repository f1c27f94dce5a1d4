"""``hrl-torch``: train any registered domain and algorithm from the command line.

    hrl-torch list
    hrl-torch train taxi --algo maxq-q --seeds 10 [--steps N] [--envs-per-seed E]
    hrl-torch train taxi --algo maxq-q --seeds 10 --backend gymnasium
    hrl-torch train taxi --algo maxq-q --resume runs/taxi__maxq-q__.../checkpoint.pt

Domains live in the repository's ``agents/`` package (not in the wheel): run from the repository
root, or pass ``--project DIR``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

os.environ.setdefault("RL_LOGGING_LEVEL", "WARNING")


def _load_domains(project: str) -> None:
    path = os.path.abspath(project)
    if path not in sys.path:
        sys.path.insert(0, path)
    try:
        importlib.import_module("agents")
    except ModuleNotFoundError as err:
        raise SystemExit(
            f"hrl-torch: no 'agents' package under {path} ({err}); run from the repository root "
            "or pass --project"
        ) from err


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hrl-torch", description=__doc__.split("\n")[0])
    parser.add_argument("--project", default=".", help="repository root holding agents/ and envs/")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="list domains and algorithms")
    train = sub.add_parser("train", help="train every seed of one algorithm as one population")
    train.add_argument("domain")
    train.add_argument("--algo", required=True)
    train.add_argument("--seeds", type=int, default=5, help="number of seeds (learners)")
    train.add_argument("--seed-offset", type=int, default=0, help="first seed")
    train.add_argument("--backend", default="torch", help="torch (batched) or gymnasium")
    train.add_argument("--envs-per-seed", type=int, default=None)
    train.add_argument("--steps", type=int, default=None, help="env steps per seed")
    train.add_argument("--eval-every", type=int, default=None)
    train.add_argument("--eval-episodes", type=int, default=None)
    train.add_argument("--threshold", type=float, default=None)
    train.add_argument("--checkpoint-every", type=int, default=None)
    train.add_argument("--out", default="runs")
    train.add_argument("--resume", default=None, help="checkpoint.pt of a run to continue")
    train.add_argument("--no-progress", action="store_true")
    train.add_argument("--no-tensorboard", action="store_true")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``hrl-torch`` command."""
    args = _parser().parse_args(argv)
    _load_domains(args.project)
    from hrl_torch import registry
    from hrl_torch.experiment import RunOptions, format_summary, run_experiment

    if args.command == "list":
        for name in registry.names():
            domain = registry.get(name)
            print(f"{name}: {domain.description} (backends: {', '.join(domain.backends)})")
            for algo, spec in sorted(domain.algos.items()):
                print(f"    --algo {algo}: {spec.description}")
        return 0
    domain = registry.get(args.domain)
    opts = RunOptions(
        seeds=list(range(args.seed_offset, args.seed_offset + args.seeds)),
        backend=args.backend,
        envs_per_learner=args.envs_per_seed,
        steps=args.steps,
        eval_every=args.eval_every,
        eval_episodes=args.eval_episodes,
        threshold=args.threshold,
        checkpoint_every=args.checkpoint_every,
        out=args.out,
        resume=args.resume,
        progress=not args.no_progress,
        tensorboard=not args.no_tensorboard,
    )
    run_dir, summary = run_experiment(domain, args.algo, opts)
    print(format_summary(summary))
    print(f"run folder: {run_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
