"""``hrl-torch``: train any registered domain and algorithm from the command line.

    hrl-torch list
    hrl-torch train taxi --algo maxq-q --seeds 10 [--steps N] [--envs-per-seed E]
    hrl-torch train taxi --algo maxq-q --seeds 10 --backend gymnasium
    hrl-torch train --resume runs/taxi__maxq-q__.../checkpoint.pt [--steps N]
    hrl-torch eval runs/taxi__maxq-q__... [--episodes N] [--worst K]
    hrl-torch sweep taxi --algo maxq-q --grid alpha=0.1,0.5 --seeds 5   (pip install -e ".[sweep]")

Domains: the repository's ``agents/`` package (not in the wheel: run from the repository root,
or pass ``--project DIR``), installed plugins (entry-point group ``hrl_torch.domains``) and
modules named with ``--domain-module MODULE``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import warnings
from pathlib import Path

from hrl_torch import __version__
from hrl_torch.common.signals import Interrupted, raise_on_signals
from hrl_torch.runs.cli_parser import UserError, parser
from hrl_torch.runs.failures import RunFailed

os.environ.setdefault("RL_LOGGING_LEVEL", "WARNING")


def _load_domains(project: str | None, modules: list[str]) -> None:
    """Register the built-in domains, plugins and ``modules``.

    The built-in domains are the ``agents`` package of ``project`` or, by default, of the
    repository this hrl-torch is installed from, never one the working folder happens to hold
    (``hrl-torch eval .`` in a folder someone sent you would run its ``agents.py``).
    ``--domain-module`` modules are also looked for in the working folder, after the rest.
    """
    from hrl_torch.runs import registry

    root = os.path.abspath(project) if project is not None else _installed_repository()
    if root is not None:
        if root in sys.path:
            sys.path.remove(root)
        sys.path.insert(0, root)
    if modules and os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    try:
        importlib.import_module("agents")
    except ModuleNotFoundError as err:
        if err.name != "agents":  # the package exists but is broken: a bug, not a user error
            raise
    try:
        registry.load_plugins()
        for module in modules:
            registry.load_module(module)
    except (ValueError, ModuleNotFoundError) as err:
        raise UserError(str(err)) from err
    if not registry.names():
        raise UserError(
            f"no domains: no 'agents' package under {root} (pass --project REPOSITORY), no "
            "installed plugin, no --domain-module"
        )


def _current_names(domain: str, algo: str | None) -> tuple[str, str | None]:
    """``registry.current_names``, its deprecation said in one line on stderr."""
    from hrl_torch.runs import registry

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always", DeprecationWarning)
        names = registry.current_names(domain, algo)
    for warning in said:
        print(f"hrl-torch: {warning.message}", file=sys.stderr)
    return names


def _installed_repository() -> str | None:
    """The repository root this hrl-torch runs from, if it holds the built-in ``agents``."""
    root = Path(__file__).resolve().parents[2]  # hrl_torch/runs/cli.py
    return str(root) if (root / "agents" / "__init__.py").is_file() else None


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``hrl-torch`` command: user errors are one line and exit code 2.

    An interrupted run (SIGINT, SIGTERM) exits with 130 / 143 after writing its checkpoint.
    """
    argv = sys.argv[1:] if argv is None else argv
    debug = "--debug" in argv
    if not argv:  # no arguments: the usage, not an error
        parser(__version__).print_help()
        return 2
    try:
        with raise_on_signals():  # SIGTERM (schedulers) is handled as Ctrl-C at every phase
            return _run(parser(__version__).parse_args(argv))
    except UserError as err:
        if debug:
            raise
        print(f"hrl-torch: error: {err}", file=sys.stderr)
        return 2
    except RunFailed as err:  # training stopped on an error: what is left is in the message
        if debug:
            raise
        print(f"hrl-torch: failed: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as err:  # outside training (a fresh run's unstarted folder is removed)
        if debug:
            raise
        name = err.signal if isinstance(err, Interrupted) else "SIGINT"
        print(f"hrl-torch: interrupted ({name})", file=sys.stderr)
        return 128 + signal.Signals[name].value
    except BrokenPipeError:  # ``hrl-torch list | head``: the reader left, nothing to report
        sys.stdout = open(os.devnull, "w")  # no flush error when Python exits
        return 0
    except Exception as err:  # a user's code (env factory, graph) or a bug: one line, exit 1
        if debug:
            raise
        from hrl_torch.runs.faults import report

        return report(err)


def _run(args: argparse.Namespace) -> int:
    import torch  # after the arguments parsed: --help and argument errors need no torch

    torch.set_num_threads(1)  # every command steps small ops (docs/design.md#threads)
    if args.project is not None and not os.path.isdir(args.project):
        raise UserError(f"--project {args.project}: no such folder")
    _load_domains(args.project, args.domain_module)
    if args.command == "list":
        return _list(args.timed)
    if args.command == "eval":
        return _evaluate(args)
    if args.command == "check":
        return _check(args.domain, args.algo)
    if args.command == "report":
        from hrl_torch.runs.aggregate import run_report_command

        try:
            return run_report_command(args)
        except ValueError as err:
            raise UserError.of(err) from err
    if args.command == "sweep":
        from hrl_torch.runs.population_grid import run_population_command
        from hrl_torch.runs.sweep import run_sweep_command

        if args.device != "cpu" and not args.population:
            raise UserError("--device is for --population sweeps (Ray trials run on the CPU)")

        try:
            return (run_population_command if args.population else run_sweep_command)(args)
        except ValueError as err:
            raise UserError.of(err) from err
    return _train(args)


def _train(args: argparse.Namespace) -> int:
    """``hrl-torch train``: the run, its summary, and the exit code of a signal."""
    from hrl_torch.common.checkpoint import CheckpointError
    from hrl_torch.common.limits import SizeLimitError
    from hrl_torch.common.safe_files import RunFolderError
    from hrl_torch.env.envcheck import EnvContractError
    from hrl_torch.hierarchy.subtask import GraphError
    from hrl_torch.runs.experiment import SettingError, format_summary, run_experiment
    from hrl_torch.runs.faults import one_line
    from hrl_torch.runs.runlock import RunLockedError

    domain, algo, opts = _train_options(args)  # every input is checked before anything is written
    if opts is None:
        return 0  # a finished run: nothing to do
    try:
        run_dir, summary = run_experiment(domain, algo, opts)
    except SettingError as err:  # refused where it is applied, before anything is written
        if not opts.settings:  # the domain's own value: a bug, not the user's input
            raise
        raise UserError(f"--set: {err}") from err
    except (
        RunLockedError,
        CheckpointError,
        EnvContractError,
        RunFolderError,
        SizeLimitError,
        GraphError,
    ) as err:  # nothing changed yet (a user's graph: with their file:line)
        raise (
            UserError(one_line(err, False)) if isinstance(err, GraphError) else UserError.of(err)
        ) from err
    print(format_summary(summary))
    print(f"run folder: {run_dir}")
    if summary["status"] == "interrupted":
        name = summary["interrupted_by"]
        print(
            f"hrl-torch: {name} at step {summary['env_steps_per_learner']}: checkpoint written; "
            f"continue with: hrl-torch train --resume {summary['checkpoint']}",
            file=sys.stderr,
        )
        return 128 + signal.Signals[name].value
    if "signal_after_training" in summary:  # the run finished; its record was written first
        name = summary["signal_after_training"]
        print(
            f"hrl-torch: {name} after training: checkpoint, summary and plots written",
            file=sys.stderr,
        )
        return 128 + signal.Signals[name].value
    return 0


def _budget(steps: int, envs: int) -> str:
    """A seed's budget: its env steps in all, taken ``envs`` at a time."""
    batched = -(-steps // envs)
    return f"{steps:,} env steps per seed in all, {envs} envs in parallel ({batched:,} steps each)"


def _list(timed: bool) -> int:
    """``hrl-torch list``: domains, algorithms, budgets (``--timed``: training time here)."""
    from hrl_torch.runs import registry

    for name in registry.names():
        try:
            domain = registry.get(name)
        except ValueError as err:  # a broken plugin does not hide the others
            print(f"{name} [{registry.source(name)}]: {err}")
            continue
        backends = ", ".join(domain.backends)
        print(f"{name} [{registry.source(name)}]: {domain.description} (backends: {backends})")
        for algo, spec in sorted(domain.algos.items()):
            budget = _budget(spec.train.steps, spec.envs_per_learner)
            if timed:
                seconds = _training_seconds(domain, algo)
                shown = f"{seconds:.1f}" if seconds < 10 else f"{seconds:,.0f}"
                budget += f", training about {shown} s per seed here"
            print(f"    --algo {algo}: {spec.description} [{budget}]", flush=True)
    return 0


def _check(name: str, algo: str | None) -> int:
    """``hrl-torch check``: the env contract and the any-device rules of each algorithm."""
    from hrl_torch.env.envcheck import EnvContractError
    from hrl_torch.runs import registry
    from hrl_torch.runs.devicecheck import check_domain
    from hrl_torch.runs.experiment import check_domain_env

    try:
        name, algo = _current_names(name, algo)
        domain = registry.get(name)
    except (KeyError, ValueError) as err:
        raise UserError(str(err).strip('"')) from err
    if algo is not None and algo not in domain.algos:
        raise UserError(f"--algo {algo}: {name} has {', '.join(sorted(domain.algos))}")
    broken = 0
    for a in [algo] if algo else sorted(domain.algos):
        try:
            check_domain_env(domain, a)
            findings = check_domain(domain, a).findings
        except EnvContractError as err:
            findings = [str(err)]
        broken += bool(findings)
        print(f"{name} --algo {a}: " + ("ok" if not findings else f"{len(findings)} finding(s)"))
        for finding in findings:
            print(f"  - {finding}", flush=True)
        for warning in _start_warnings(domain, a):
            print(f"  - warning: {warning}", flush=True)
    return 1 if broken else 0


def _start_warnings(domain, algo: str) -> list[str]:
    """What the trainer's start would warn about the algorithm's initial values (not errors)."""
    from hrl_torch.learners.init_check import discount_traps, warn_discount_trap

    spec = domain.algos[algo]
    learner = spec.make_learner(spec.make_graph(), 1)
    if not discount_traps(learner):
        return []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return warn_discount_trap(learner)


def _training_seconds(domain, algo: str, steps: int = 10) -> float:
    """The budget's training time of one seed on this machine, from ``steps`` timed steps."""
    import time

    from hrl_torch.runs.experiment import RunOptions, build_trainer

    opts = RunOptions(seeds=[0], eval_episodes=0, progress=False, tensorboard=False)
    trainer = build_trainer(domain, algo, opts)
    for _ in range(3):  # warm up
        trainer.train_step()
    start = time.perf_counter()
    for _ in range(steps):
        trainer.train_step()
    per_step = (time.perf_counter() - start) / steps
    trainer.close()
    return per_step * trainer.config.steps / trainer.E


def _evaluate(args: argparse.Namespace) -> int:
    """``hrl-torch eval RUN_DIR``: per-seed means and the worst episodes; writes nothing."""
    from hrl_torch.common.checkpoint import CheckpointError
    from hrl_torch.runs.experiment import evaluate_run
    from hrl_torch.training.runlog import fields_text

    try:
        trainer, records = evaluate_run(args.run_dir, args.episodes)
    except (KeyError, FileNotFoundError, CheckpointError, ValueError) as err:
        raise UserError.of(err) from err
    run = trainer.run_config
    print(f"{run['domain']} / {run['algo']} at step {trainer.step}, greedy evaluation:")
    if records is None:
        values, _ = trainer.evaluate()
        for seed, v in zip(run["seeds"], values.tolist(), strict=True):
            print(f"  seed {seed}: {trainer.evaluator.tags[0]} {v:.3f}")
        print("(a continuing domain: no episodes to list)")
        return 0
    n = records.batch_size[0] // trainer.P
    for p, seed in enumerate(run["seeds"]):
        mine = records[p * n : (p + 1) * n]
        print(
            f"  seed {seed}: return {float(mine['return'].mean()):.3f}, "
            f"success {float(mine['success'].float().mean()):.2f}, "
            f"length {float(mine['length'].mean()):.1f} over {n} episodes"
        )
    order = sorted(range(records.batch_size[0]), key=lambda r: float(records["return"][r]))
    if args.worst:
        print(f"worst {min(args.worst, len(order))} episodes:")
    names = trainer.graph.names
    for r in order[: args.worst]:
        k = int(records["n_decisions"][r])
        decisions = " ".join(names[int(x)] for x in records["decisions"][r, :k])
        flags = ("success" if bool(records["success"][r]) else "failure") + (
            ", truncated" if bool(records["truncated"][r]) else ""
        )
        print(
            f"  seed {int(records['seed'][r])} episode {int(records['episode'][r])}: "
            f"return {float(records['return'][r]):.3f}, length {int(records['length'][r])} "
            f"({flags}); start {fields_text(records['start'][r])}; root: {decisions}"
        )
    return 0


def _train_options(args: argparse.Namespace):
    """``(domain, algo, RunOptions)`` of ``hrl-torch train``, every input checked.

    ``opts`` is ``None`` for a resumed run that has already finished (said on stdout).
    """
    from hrl_torch.common.checkpoint import CheckpointError, load_checkpoint
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, check_choice
    from hrl_torch.runs.sweep import logger_names
    from hrl_torch.training.steps import single_agent_only

    given, _ = _given_options(args)
    try:
        loggers = logger_names(args.logger)
    except ValueError as err:
        raise UserError.of(err) from err
    display = {
        "progress": not args.no_progress,
        "tensorboard": "tensorboard" in loggers and not args.no_tensorboard,
        "trackers": tuple(n for n in loggers if n != "tensorboard"),
        "check_leaf_rewards": args.check_leaf_rewards,
        "cuda_graph": not args.no_cuda_graph,
        "compile_step": args.compile_step,
    }
    try:
        state = load_checkpoint(args.resume) if args.resume else None
        if state is not None and "run" in state:
            return _continuation(args, state, given, display)
        if args.domain is None or args.algo is None:
            if state is not None:
                raise UserError(
                    f"{args.resume} records no run configuration (written by an older "
                    "hrl-torch): give the domain, --algo and the original run's options"
                )
            missing = "the domain" if args.domain is None else "--algo"
            raise UserError(f"train needs {missing} (or --resume CHECKPOINT)")
        args.domain, args.algo = _current_names(args.domain, args.algo)
        domain = registry.get(args.domain)
        spec = check_choice(domain, args.algo, given.get("backend", "torch"))
        if args.collector:  # (a one-row env says whether it is multi-agent)
            backend = given.get("backend", "torch")
            single_agent_only(domain.make_env([0], 1, backend, **spec.env_options))
    except (KeyError, FileNotFoundError, CheckpointError, ValueError) as err:
        raise UserError.of(err) from err
    given.setdefault("seeds", list(range(5)))
    out = "runs" if args.out is None else args.out
    if not out.strip():
        raise UserError("--out must name a folder, got an empty string")
    try:
        opts = RunOptions(**given, **display, out=out, resume=args.resume)
    except ValueError as err:
        raise UserError.of(err) from err
    _check_writable_folder(out, "--out")
    return domain, args.algo, opts


def _given_options(args: argparse.Namespace) -> tuple[dict, dict]:
    """The run options ``hrl-torch train`` was given (``RunOptions`` fields) and its ``--set``."""
    given = {
        "steps": args.steps,
        "checkpoint_every": args.checkpoint_every,
        "eval_every": args.eval_every,
        "eval_episodes": args.eval_episodes,
        "threshold": args.threshold,
        "envs_per_learner": args.envs_per_seed,
        "backend": args.backend,
        "device": args.device,
        "collector": args.collector or None,
    }
    if args.seeds is not None or args.seed_offset is not None:
        first, n = args.seed_offset or 0, args.seeds or 5
        given["seeds"] = list(range(first, first + n))
    given = {k: v for k, v in given.items() if v is not None}
    settings = _parsed_settings(args.set)  # --set: the names the sweep takes
    given |= {"settings": settings} if settings else {}
    return given, settings


def _parsed_settings(items: list[str]) -> dict:
    """``--set NAME=VALUE`` items by name (a malformed item: one line)."""
    from hrl_torch.common.config import parse_settings

    try:
        return parse_settings(items)
    except ValueError as err:
        raise UserError.of(err) from err


def _check_writable_folder(path: str, option: str) -> None:
    """``path`` is (or is made now as) a folder this process may write in."""
    existing = os.path.abspath(path)
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise UserError(f"{option} {path}: {existing} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UserError(f"{option} {path}: {existing} is not writable")
    try:  # some folders say writable and are not (/proc, a read-only mount)
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise UserError(f"{option} {path}: cannot make the folder ({err.strerror})") from err


def _continuation(args, state: dict, given: dict, display: dict):
    """``_train_options`` for a checkpoint that records its run."""
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import continue_options, recorded_run

    run = recorded_run(state["run"])
    if args.domain is not None:
        args.domain, args.algo = _current_names(args.domain, args.algo)
    if args.out is not None:
        raise UserError("--out does not apply to --resume: a run continues in its own folder")
    _check_writable_folder(os.path.dirname(os.path.abspath(args.resume)), "--resume")
    named = {"domain": args.domain, "algo": args.algo}
    opts = continue_options(
        args.resume, run, **{k: v for k, v in named.items() if v is not None}, **given, **display
    )
    step = int(state["trainer"]["step"])
    curve = state["trainer"].get("curve") or []  # (a signal may have cut the final evaluation)
    evaluated = not run.get("eval_episodes") or bool(curve and int(curve[-1][0]) == step)
    if step >= opts.steps and evaluated:
        print(
            f"{args.resume}: the run finished at step {step} (budget {opts.steps}); "
            f"nothing to do (pass --steps N > {step} to continue it)"
        )
        return None, None, None
    return registry.get(run["domain"]), run["algo"], opts


if __name__ == "__main__":
    sys.exit(main())
