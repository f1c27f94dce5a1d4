"""The ``hrl-torch`` command line's arguments, in a module that imports no torch.

``hrl-torch --help`` (and any mistake in the arguments) is answered from here alone, so it
does not wait for torch, tensordict and TorchRL to import (about 3 s).
"""

from __future__ import annotations

import argparse

from hrl_torch.runs.argtypes import finite, int_at_least

DESCRIPTION = "hrl-torch: train any registered domain and algorithm from the command line."
DOMAIN_DEFAULT = "(default: the domain's)"


class UserError(Exception):
    """A mistake in the command line: one line on stderr, exit code 2, nothing written."""

    @classmethod
    def of(cls, err: Exception) -> UserError:
        """The library's error (a ``KeyError``, ``ValueError``, ...) as a user error."""
        return cls(err.args[0] if err.args else str(err))


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        raise UserError(message)


def device(text: str) -> str:
    """A torch device that exists on this machine (``--device``); ``meta`` is accepted."""
    from hrl_torch.common.devices import check_device

    try:
        return check_device(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from err


def parser(version: str) -> argparse.ArgumentParser:
    """The parser of every ``hrl-torch`` command."""
    top = _Parser(prog="hrl-torch", description=DESCRIPTION)
    top.add_argument("--version", action="version", version=f"hrl-torch {version}")
    top.add_argument(
        "--project",
        default=None,
        help="repository root holding agents/ and envs/ (default: the one hrl-torch is "
        "installed from; never the working folder's)",
    )
    top.add_argument(
        "--domain-module",
        action="append",
        default=[],
        metavar="MODULE",
        help="import MODULE and register its DOMAIN / DOMAINS (repeatable)",
    )
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    listing = sub.add_parser("list", help="list domains, algorithms and their default budgets")
    listing.add_argument(
        "--timed",
        action="store_true",
        help="also time a few training steps of each algorithm: its budget's training time "
        "for one seed on this machine (evaluation not included; about a minute in all)",
    )
    train = _train_parser(sub)
    sweep = add_sweep_parser(sub)
    evaluate = sub.add_parser(
        "eval", help="re-evaluate a run's checkpoint greedily and show its worst episodes"
    )
    evaluate.add_argument("run_dir", help="a run folder (holding checkpoint.pt)")
    evaluate.add_argument(
        "--episodes", type=int_at_least(1), default=None, help="per seed (default: the run's)"
    )
    evaluate.add_argument(
        "--worst", type=int_at_least(0), default=10, help="episodes to show (default: 10)"
    )
    check = sub.add_parser(
        "check",
        help="check a domain's env contract and, without a GPU, that its training step runs "
        "on any device with no host read (docs/your-own-hierarchy.md)",
    )
    check.add_argument("domain", help="a name `hrl-torch list` shows")
    check.add_argument("--algo", default=None, help="one algorithm (default: every one)")
    report = _report_parser(sub)
    for p in (top, train, evaluate, sweep, check, report):
        p.add_argument("--debug", action="store_true", help="tracebacks for every error")
    return top


def _report_parser(sub) -> argparse.ArgumentParser:
    """``hrl-torch report``; ``hrl_torch.runs.aggregate.run_report_command`` runs it."""
    report = sub.add_parser(
        "report",
        help="a table across runs and tasks: IQM, mean, optimality gap, 95%% bootstrap "
        "intervals (rliable)",
        epilog="Needs the track extra: pip install 'hrl-torch[track]'. docs/runs.md, Reports.",
    )
    report.add_argument(
        "run_dirs", nargs="+", metavar="RUN_DIR", help="run folders, or folders holding them"
    )
    report.add_argument(
        "--metric", default=None, help="the per-seed key of summary.json (default: the final "
        "greedy return, or throughput on continuing domains)",
    )  # fmt: skip
    report.add_argument(
        "--reference",
        action="append",
        default=[],
        metavar="DOMAIN=VALUE",
        help="the score that counts as 1 across tasks (default: the run's threshold)",
    )
    report.add_argument(
        "--out", default=None, help="folder for report.md and report.csv (default: report/ "
        "beside the run folders)",
    )  # fmt: skip
    report.add_argument(
        "--reps", type=int_at_least(100), default=2000, help="bootstrap replications (2000)"
    )
    report.add_argument("--seed", type=int_at_least(0), default=0, help="of the bootstrap (0)")
    return report


def _train_parser(sub) -> argparse.ArgumentParser:
    train = sub.add_parser(
        "train",
        help="train every seed of one algorithm as one population",
        epilog="With --resume the checkpoint's run continues: the domain, --algo and the "
        "run's options come from the checkpoint; only --steps and --checkpoint-every may change.",
    )
    positive, natural = int_at_least(1), int_at_least(0)
    train.add_argument("domain", nargs="?", default=None, help="a name `hrl-torch list` shows")
    train.add_argument("--algo", default=None, help="one of the domain's algorithms (see list)")
    train.add_argument("--seeds", type=positive, default=None, help="number of seeds (default: 5)")
    train.add_argument("--seed-offset", type=natural, default=None, help="first seed (default: 0)")
    train.add_argument(
        "--backend",
        default=None,
        help="env backend: torch (batched, default) or one the domain lists (gymnasium, ...)",
    )
    train.add_argument(
        "--envs-per-seed", type=positive, default=None, help=f"env rows per seed {DOMAIN_DEFAULT}"
    )
    train.add_argument(
        "--steps", type=positive, default=None, help=f"env steps per seed {DOMAIN_DEFAULT}"
    )
    train.add_argument(
        "--eval-every", type=natural, default=None, help=f"0: only at the end {DOMAIN_DEFAULT}"
    )
    train.add_argument(
        "--eval-episodes", type=natural, default=None, help=f"0: no evaluation {DOMAIN_DEFAULT}"
    )
    train.add_argument(
        "--threshold", type=finite, default=None, help=f"greedy score to reach {DOMAIN_DEFAULT}"
    )
    train.add_argument(
        "--checkpoint-every", type=natural, default=None, help="0: at the end (default: 0)"
    )
    train.add_argument("--out", default=None, help="parent folder of run folders (default: runs)")
    train.add_argument("--resume", default=None, help="checkpoint.pt of a run to continue")
    train.add_argument("--device", type=device, default=None, help="cpu (default), cuda, ...")
    _add_switches(train)
    _add_set(train)
    return train


def _add_switches(train: argparse.ArgumentParser) -> None:
    """``train``'s on/off flags: how the steps run and what the run writes."""
    train.add_argument(
        "--collector", action="store_true", help="step through a TorchRL Collector's frames"
    )
    train.add_argument(
        "--check-leaf-rewards",
        action="store_true",
        help="warn when one abstract state of a primitive sees different rewards",
    )
    train.add_argument(
        "--no-progress", action="store_true", help="no progress bar: one line per evaluation"
    )
    train.add_argument(
        "--no-cuda-graph",
        action="store_true",
        help="on a CUDA device, run every training step eagerly (default: replay a CUDA graph)",
    )
    train.add_argument(
        "--compile-step",
        action="store_true",
        help="on the CPU, run the recorded training step compiled by inductor (small batches)",
    )
    train.add_argument(
        "--no-tensorboard", action="store_true", help="write no TensorBoard event files"
    )
    train.add_argument(
        "--logger",
        action="append",
        default=None,
        metavar="NAMES",
        help="where scalars go besides progress.csv: tensorboard (default), csv, wandb (offline), "
        "mlflow (SQLite); a comma list or repeated, all inside the run folder (wandb and mlflow: "
        "pip install 'hrl-torch[track]')",
    )


def _add_set(train: argparse.ArgumentParser) -> None:
    """``train --set NAME=VALUE`` (``hrl_torch.common.config.parse_settings`` reads it)."""
    train.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="one setting, e.g. learner.alpha=0.2 or exploration.epsilon.end=0.01 (repeatable; "
        "the names of sweep --grid)",
    )


def add_sweep_parser(sub) -> argparse.ArgumentParser:
    """``hrl-torch sweep``; ``hrl_torch.runs.sweep.run_sweep_command`` runs it."""
    positive = int_at_least(1)
    p = sub.add_parser(
        "sweep",
        help="run a grid of hyperparameters as Ray Tune trials, one population run each",
        epilog='Ray needs the sweep extra: pip install -e ".[sweep]" (not with --in-process or '
        "--population). Grid names: TrainConfig fields, envs_per_learner, and the dotted fields "
        "of the learner, exploration and PG setting (learner.alpha, exploration.epsilon.end, "
        "pg.alpha; an unknown name is refused with the list).",
    )
    p.add_argument("domain", help="a name `hrl-torch list` shows")
    p.add_argument("--algo", required=True, help="one of the domain's algorithms")
    p.add_argument(
        "--grid",
        action="append",
        required=True,
        metavar="NAME=V1,V2",
        help="values of one hyperparameter (repeatable; the sweep runs their product)",
    )
    p.add_argument("--seeds", type=positive, default=5, help="seeds per trial (default: 5)")
    p.add_argument(
        "--steps", type=positive, default=None, help=f"env steps per seed {DOMAIN_DEFAULT}"
    )
    p.add_argument("--address", default=None, help="an existing Ray cluster (default: local)")
    p.add_argument("--out", default="runs", help="parent of the sweep folder (default: runs)")
    p.add_argument("--name", default=None, help="sweep folder (default: DOMAIN__ALGO__sweep)")
    p.add_argument("--resume", action="store_true", help="continue the sweep in its folder")
    p.add_argument(
        "--in-process",
        action="store_true",
        help="no Ray: run the trials one after another in this process",
    )
    p.add_argument(
        "--population",
        action="store_true",
        help="train the whole grid x seeds as one population in this process (no Ray; the "
        "settings that differ must be per-learner ones: learner.alpha, learner.init, "
        "exploration.epsilon.*)",
    )
    p.add_argument(
        "--device", type=device, default="cpu", help="with --population: cpu (default), cuda, ..."
    )
    p.add_argument(
        "--logger",
        action="append",
        default=None,
        metavar="NAMES",
        help="what each trial's run logs to, as train --logger (default: tensorboard; not with "
        "--population)",
    )
    return p
