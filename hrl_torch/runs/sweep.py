"""Hyperparameter sweeps on Ray Tune: each configuration is one population run.

    hrl-torch sweep taxi --algo maxq-q --grid learner.alpha=0.1,0.5 \
        --grid exploration.epsilon.end=0.01,0.05 --seeds 5

The grid's product of values gives the configurations; each is one Ray Tune trial that trains
every seed at once through ``run_experiment``. Ray is an optional extra
(``pip install -e ".[sweep]"``), imported only when a sweep starts. Layout of
``{out}/{name}/``::

    sweep.json            the request (domain, algorithm, grid, seeds, steps, metric)
    sweep.csv, sweep.md   configurations ranked by the IQM over seeds, with its 95% bootstrap
                          interval (rliable's, ``common.stats``) and the mean
    <label>/<run folder>  one ordinary run folder per trial (label: ``alpha=0.1_init=-20``), so
                          ``tensorboard --logdir {out}/{name}`` groups the trials
    tune/                 Ray Tune's experiment state, restored by ``resume=True``

A value reaches its run through ``hrl_torch.runs.domain.with_overrides`` (the names it takes are
listed there): a new ``AlgoSpec`` by ``dataclasses.replace``, nothing patched, so trials may
run side by side in one process.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import json
import math
import os
import shutil
import sys
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hrl_torch.common.config import parse_value, split_name
from hrl_torch.common.stats import bootstrap_interval
from hrl_torch.runs.domain import TRAIN_KEYS, AlgoSpec, DomainSpec, setting_names, with_overrides  # noqa: F401 (re-exported)
from hrl_torch.runs.experiment import RunOptions, check_choice, check_domain_env, run_experiment
from hrl_torch.training.runlog import mean_ci95
from hrl_torch.training.trackers import check_trackers

INSTALL_HINT = 'Ray is not installed: pip install -e ".[sweep]"'


# ---------------------------------------------------------------------- the grid
def parse_grid(items: Sequence[str]) -> dict[str, list]:
    """``["learner.alpha=0.1,0.5", "steps=100"]`` -> ``{"learner.alpha": [0.1, 0.5], ...}``.

    Names are dotted (``exploration.epsilon.end``; ``with_overrides`` says which exist).
    Values are whole numbers (``int``), other finite numbers (``float``) or ``true`` /
    ``false``. A malformed item, a repeated name or value raises ``ValueError`` naming the item.
    """
    grid: dict[str, list] = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip()
        if not sep or split_name(name) is None:
            raise ValueError(
                f"grid item {item!r}: expected NAME=V1,V2,... (e.g. learner.alpha=0.1,0.5)"
            )
        if name in grid:
            raise ValueError(f"grid item {item!r}: {name} is given twice")
        parsed = [parse_value(item, text.strip()) for text in values.split(",")]
        if len(set(map(repr, parsed))) < len(parsed):
            raise ValueError(f"grid item {item!r}: a value is repeated")
        grid[name] = parsed
    return grid


def configurations(grid: dict[str, list]) -> list[dict]:
    """Every combination of the grid's values, the last name varying fastest."""
    return [dict(zip(grid, values, strict=True)) for values in itertools.product(*grid.values())]


def label(config: dict) -> str:
    """Folder name of a configuration: ``alpha=0.1_init=-20``."""
    return "_".join(f"{k}={v}" for k, v in config.items()) or "default"


# ---------------------------------------------------------------------- the sweep
def default_metric(domain: DomainSpec) -> str:
    """The ``per_seed`` key that ranks configurations: throughput on continuing tasks."""
    return "final_eval_throughput" if domain.make_evaluator is not None else "final_eval_return"


def _checked_request(domain_name, algo, grid, seeds, steps, metric):
    """``run_sweep``'s arguments checked before Ray starts or a file is written.

    Returns ``(domain, seeds as a list, metric, the request as recorded, configurations)``.
    """
    from hrl_torch.runs import registry

    try:
        domain = registry.get(domain_name)
        check_choice(domain, algo, "torch")
    except KeyError as err:
        raise ValueError(err.args[0]) from None
    seeds = list(range(seeds)) if isinstance(seeds, int) else list(seeds)
    if not seeds:
        raise ValueError("a sweep needs at least one seed")
    if steps is not None and "steps" in grid:
        raise ValueError("steps is both swept (--grid steps=...) and fixed (--steps)")
    metric = metric or default_metric(domain)
    request = {"domain": domain_name, "algo": algo, "grid": grid, "seeds": seeds, "steps": steps}
    request = json.loads(json.dumps({**request, "metric": metric}))
    configs = configurations(grid)
    _check_configurations(domain.algos[algo], configs)
    check_domain_env(domain, algo)
    return domain, seeds, metric, request, configs


def run_sweep(
    domain_name: str,
    algo: str,
    grid: dict[str, list],
    seeds: int | Sequence[int],
    out: str | Path = "runs",
    address: str | None = None,
    steps: int | None = None,
    resume: bool = False,
    metric: str | None = None,
    name: str | None = None,
    in_process: bool = False,
    loggers: Sequence[str] = ("tensorboard",),
) -> list[dict]:
    """Run every configuration of ``grid`` as one Ray Tune trial (or here, in turn); rank them.

    Args:
        domain_name: a registered domain (import ``agents`` or a plugin first).
        algo: one of its algorithms.
        grid: name -> values (``parse_grid``); names as ``with_overrides`` allows.
        seeds: number of seeds (``0..n-1``) or the seeds; every trial trains them all.
        out: parent of the sweep folder.
        address: an existing Ray cluster (``ray.init(address=...)``); ``None``: a local Ray
            with this machine's CPUs, one trial per CPU.
        steps: env steps per learner (``None``: the algorithm's default or the grid's).
        resume: continue the sweep in ``{out}/{name}`` (Tune's experiment restore: finished
            trials are kept, unfinished and errored ones run again); the request must equal
            the recorded one. Without it the folder must not hold a started sweep.
        metric: the ``summary.json`` per-seed key to rank by, higher is better (default:
            ``final_eval_return``, or ``final_eval_throughput`` on continuing domains).
        name: the sweep folder's name (default ``{domain}__{algo}__sweep``).
        in_process: no Ray: the trials run one after another in this process, into the same
            folders (resume reuses the finished ones; a signal stops the sweep, the trials
            left are ``unfinished``).
        loggers: what each trial's run logs to, as ``train --logger``: ``tensorboard``,
            ``csv``, ``wandb``, ``mlflow`` (``hrl_torch.training.trackers``), inside its folder.

    Returns:
        The rows of ``rank`` (also written to ``sweep.csv`` and ``sweep.md``): per
        configuration its ``status``, ``rank``, ``mean``, ``ci95`` (half-width), ``per_seed``
        values and ``run_dir``.

    Raises:
        ValueError: a user error (unknown domain, algorithm or key, bad value, the folder,
            Ray missing), before Ray starts; or no connection to the cluster at ``address``.
    """
    if in_process and address is not None:
        raise ValueError("--in-process runs no Ray: it takes no --address")
    domain, seeds, metric, request, configs = _checked_request(
        domain_name, algo, grid, seeds, steps, metric
    )
    logs = {"tensorboard": "tensorboard" in loggers}
    logs["trackers"] = check_trackers([n for n in loggers if n != "tensorboard"])
    sweep_dir = Path(out).resolve() / (name or f"{domain_name}__{algo}__sweep")
    _check_folder(sweep_dir, request, resume)
    if in_process:
        results = _fit_in_process(domain, algo, configs, seeds, steps, metric, sweep_dir, logs)
    else:
        run = (seeds, steps, metric, sweep_dir, logs)
        results = _fit_on_ray(domain, algo, grid, run, resume, address)
    rows = rank(configs, results, metric)
    write_table(rows, list(grid), metric, sweep_dir)
    return rows


def _fit_on_ray(domain, algo, grid, run: tuple, resume, address):
    """Tune's results, on a local Ray started here (and stopped) or the cluster at ``address``.

    ``run``: ``(seeds, steps, metric, sweep_dir, logs)`` of every trial.
    """
    ray, tune = _import_ray()
    started = not ray.is_initialized()
    if started:
        _start_ray(ray, address, _worker_path(domain))
    try:
        return _fit(tune, domain, algo, grid, *run, resume)
    finally:
        if started:
            ray.shutdown()


def _check_configurations(spec: AlgoSpec, configs: list[dict]) -> None:
    """Build every configuration's learner and exploration once: bad ones are ``ValueError``."""
    for config in configs:
        changed = with_overrides(spec, config)
        try:
            changed.make_learner(changed.make_graph(), 1)
            changed.make_exploration(changed.train)
        except (TypeError, ValueError) as err:
            raise ValueError(f"configuration {label(config)}: {err}") from None


def _check_folder(sweep_dir: Path, request: dict, resume: bool) -> None:
    """Record the request in ``sweep.json``; a started sweep needs ``resume`` and the same one.

    A sweep has started once Tune made its folder (``tune/``) or a trial its folder; a folder
    that only holds the ``sweep.json`` of a sweep that never reached a trial is reused.
    """
    recorded = sweep_dir / "sweep.json"
    if sweep_dir.is_dir() and any(p.is_dir() for p in sweep_dir.iterdir()):
        if not resume:
            raise ValueError(
                f"{sweep_dir} holds a sweep: pass --resume to continue it or --name for a new one"
            )
        old = json.loads(recorded.read_text())
        changed = [k for k in request if old.get(k) != request[k]]
        if changed:
            key = changed[0]
            raise ValueError(
                f"--resume: {key} {request[key]!r} differs from the sweep's ({old.get(key)!r}); "
                f"a resumed sweep keeps its request ({recorded})"
            )
    sweep_dir.mkdir(parents=True, exist_ok=True)
    recorded.write_text(json.dumps(request, indent=2))


def _import_ray():
    try:
        import ray
        from ray import tune
    except ImportError:
        raise ValueError(INSTALL_HINT) from None
    return ray, tune


def _worker_path(domain: DomainSpec) -> str:
    """``PYTHONPATH`` for Ray workers: the domain's source root, the cwd, the current value.

    The workers unpickle the domain, so they import its modules (e.g. ``agents.taxi``).
    """
    module = sys.modules.get(getattr(domain.make_env, "__module__", "").split(".")[0])
    paths = [os.getcwd(), os.environ.get("PYTHONPATH", "")]
    if getattr(module, "__file__", None):  # a package's parent folder, or a module's own
        file = Path(module.__file__).resolve()
        paths.insert(0, str(file.parents[1] if hasattr(module, "__path__") else file.parent))
    return os.pathsep.join(p for p in dict.fromkeys(paths) if p)


def _start_ray(ray, address: str | None, pythonpath: str) -> None:
    """A local Ray with a small footprint, or a connection to the cluster at ``address``."""
    runtime_env = {"env_vars": {"PYTHONPATH": pythonpath, "RL_LOGGING_LEVEL": "WARNING"}}
    if address:
        try:
            ray.init(address=address, runtime_env=runtime_env, log_to_driver=False)
        except (ConnectionError, ray.exceptions.AuthenticationError) as err:
            raise ValueError(
                f"cannot connect to the Ray cluster at {address} ({type(err).__name__}); with "
                "token authentication on, set RAY_AUTH_MODE=token and give its token"
            ) from None
        return
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no internet: no usage reports
    ray.init(
        address="local",  # a new instance, even when a cluster runs on this machine
        num_cpus=os.cpu_count() or 1,
        include_dashboard=False,
        object_store_memory=100 * 2**20,
        runtime_env=runtime_env,
        log_to_driver=False,
    )


def _fit(tune, domain, algo, grid, seeds, steps, metric, sweep_dir: Path, logs, resume: bool):
    """Tune's results of the sweep (restored when ``resume`` and Tune's folder exists)."""
    from ray.tune.logger import CSVLoggerCallback, JsonLoggerCallback

    trainable = tune.with_parameters(
        _trial, domain=domain, algo=algo, seeds=seeds, steps=steps, metric=metric,
        root=sweep_dir, logs=logs,
    )  # fmt: skip
    path = sweep_dir / "tune"
    if resume and tune.Tuner.can_restore(str(path)):
        tuner = tune.Tuner.restore(
            str(path), trainable, resume_unfinished=True, resume_errored=True
        )
    else:
        tuner = tune.Tuner(
            trainable,
            param_space={k: tune.grid_search(v) for k, v in grid.items()},
            tune_config=tune.TuneConfig(trial_dirname_creator=_trial_dirname),
            run_config=tune.RunConfig(
                name="tune",
                storage_path=str(sweep_dir),
                verbose=1,
                # Tune's own TensorBoard files would sit beside the runs' in the sweep folder
                callbacks=[CSVLoggerCallback(), JsonLoggerCallback()],
            ),
        )
    with _environ(TUNE_DISABLE_AUTO_CALLBACK_LOGGERS="1"):
        return tuner.fit()


@contextmanager
def _environ(**values: str):
    """Environment variables set within the block (restored after)."""
    before = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                del os.environ[k]
            else:
                os.environ[k] = v


def _trial_dirname(trial) -> str:
    return label(trial.config)


def _trial(config: dict, domain, algo, seeds, steps, metric, root, logs=None) -> None:
    """One trial in a Ray worker: ``trial_report``, reported to Tune."""
    from ray import tune

    report = trial_report(config, domain, algo, seeds, steps, metric, root, logs)
    report.pop("status")
    tune.report(report)


@dataclasses.dataclass
class TrialResult:
    """What ``rank`` reads of a trial (the fields of Tune's ``Result`` it uses)."""

    config: dict
    metrics: dict
    error: Exception | None = None


def _fit_in_process(domain, algo, configs, seeds, steps, metric, sweep_dir: Path, logs=None):
    """Every configuration's trial in turn, here; an interrupted trial ends the sweep."""
    results = []
    for config in configs:
        try:
            report = trial_report(config, domain, algo, seeds, steps, metric, sweep_dir, logs)
        except Exception as err:  # recorded in its row, as Tune records an errored trial
            results.append(TrialResult(config, {}, err))
            continue
        if report.pop("status") != "finished":
            break  # a signal stopped the run: it and the trials after it stay unfinished
        results.append(TrialResult(config, report))
    return results


def trial_report(config: dict, domain, algo, seeds, steps, metric, root, logs=None) -> dict:
    """One trial: a population run into ``root/<label>/``; its metric's mean and per seed.

    ``logs``: the run's ``tensorboard`` and ``trackers`` options (``None``: TensorBoard only).

    A run left unfinished by an earlier attempt of this trial is removed; a finished one is
    reported again rather than rerun. The settings reach the run as ``RunOptions.settings``
    (``with_overrides``; its checkpoint records them, so ``train --resume`` continues it).
    """
    trial_dir = Path(root) / label(config)
    done = _finished_run(trial_dir)
    if done is None:
        shutil.rmtree(trial_dir, ignore_errors=True)
        opts = RunOptions(
            seeds=seeds,
            steps=steps,
            out=str(trial_dir),
            progress=False,
            check_env=False,
            settings=dict(config),
            **(logs or {}),
        )
        run_dir, summary = run_experiment(domain, algo, opts)
    else:
        run_dir, summary = done
    values = [row.get(metric) for row in summary["per_seed"]]
    if any(v is None for v in values):
        raise KeyError(
            f"summary.json has no per-seed {metric!r}; it has {sorted(summary['per_seed'][0])}"
        )
    mean, half = mean_ci95(np.array(values, dtype=float)[:, None])
    report = {metric: float(mean[0]), "ci95": float(half[0]), "run_dir": str(run_dir)}
    report.update({f"seed_{s}": float(v) for s, v in zip(seeds, values, strict=True)})
    return {**report, "status": summary["status"]}


def _finished_run(trial_dir: Path) -> tuple[Path, dict] | None:
    """The run folder in ``trial_dir`` whose ``summary.json`` says finished, if any."""
    for path in sorted(trial_dir.glob("*/summary.json")):
        summary = json.loads(path.read_text())
        if summary.get("status") == "finished":
            return path.parent, summary
    return None


# ---------------------------------------------------------------------- the table
def rank(configs: list[dict], results, metric: str) -> list[dict]:
    """One row per configuration: the finished ones first, best IQM over seeds first.

    The statistics come from each trial's ``summary.json``; ``status`` is ``finished``
    (ranked), ``error`` (``error`` says why) or ``unfinished`` (an interrupted sweep: resume
    runs it). ``results``: Tune's ``ResultGrid``.
    """
    by_label = {label(r.config): r for r in results if r.config is not None}
    rows = []
    for config in configs:
        row = {"config": config, "metric": metric, "rank": None, "status": "unfinished"}
        result = by_label.get(label(config))
        run_dir = None if result is None else (result.metrics or {}).get("run_dir")
        if result is not None and result.error is not None:
            row.update(status="error", error=_last_line(result.error))
        elif run_dir is not None:
            row.update(status="finished", **_statistics(Path(run_dir), metric))
        rows.append(row)
    finished = assign_ranks([r for r in rows if r["status"] == "finished"])
    return finished + [r for r in rows if r["status"] != "finished"]


def seed_statistics(values: np.ndarray) -> dict:
    """IQM over seeds with its 95% bootstrap interval (``common.stats``: rliable's), and the mean.

    ``ci95`` is the half-width of the mean's Student-t interval (the 0.2 tables' statistic, kept
    in the rows; NaN with one seed). Seeds without a value (NaN) are left out.
    """
    finite = values[np.isfinite(values)]
    mean, half = (float(x[0]) for x in mean_ci95(values[:, None]))
    row = {"iqm": math.nan, "iqm_low": math.nan, "iqm_high": math.nan}
    if finite.size:
        point, lo, hi = bootstrap_interval(finite[:, None])
        row.update(iqm=float(point[0]), iqm_low=float(lo[0]), iqm_high=float(hi[0]))
    n = int(finite.size)
    return {**row, "mean": mean, "ci95": half if n > 1 else math.nan, "n_seeds": n}


def assign_ranks(rows: list[dict]) -> list[dict]:
    """``rows`` best IQM first (then best mean); equal IQM and mean share a rank (1, 1, 3).

    Rows without a score come last, unranked by each other (they share the last rank).
    """

    def score(row):
        return tuple(-row[k] if row[k] == row[k] else math.inf for k in ("iqm", "mean"))

    rows = sorted(rows, key=score)  # stable: rows that tie keep the grid's order on the page
    for k, row in enumerate(rows):
        tied = k > 0 and score(row) == score(rows[k - 1])
        row["rank"] = rows[k - 1]["rank"] if tied else k + 1
    return rows


def _statistics(run_dir: Path, metric: str) -> dict:
    """``seed_statistics`` of ``metric`` over the seeds of a run's summary."""
    summary = json.loads((run_dir / "summary.json").read_text())
    values = np.array([r[metric] for r in summary["per_seed"]], dtype=float)
    return {
        **seed_statistics(values),
        "per_seed": values.tolist(),
        "train_seconds": summary["train_seconds"],
        "run_dir": str(run_dir),
    }


def _last_line(error) -> str:
    """The exception's own message: the last line of a worker's traceback."""
    lines = [line for line in str(error).splitlines() if line.strip()]
    return lines[-1].strip() if lines else type(error).__name__


def write_table(rows: list[dict], keys: list[str], metric: str, sweep_dir: Path) -> None:
    """``sweep.csv`` (full precision) and ``sweep.md`` of ranked rows."""
    head = ["rank", *keys, f"IQM {metric}", "IQM 95% low", "IQM 95% high", "mean"]
    head += ["seeds", "train s", "run"]
    csv_rows, md_rows = [], []
    for row in rows:
        config = [row["config"][k] for k in keys]
        if row["status"] != "finished":
            why = row.get("error") or "unfinished (resume the sweep)"
            csv_rows.append(["", *config, "", "", "", "", "", "", why])
            md_rows.append(["-", *config, "", "", "", "", "", "", why])
            continue
        stats = [row["iqm"], row["iqm_low"], row["iqm_high"], row["mean"]]
        run = os.path.relpath(row["run_dir"], sweep_dir)
        rest = [row["n_seeds"], row["train_seconds"], run]
        csv_rows.append([row["rank"], *config, *stats, *rest])
        md_rows.append([row["rank"], *config, *(f"{x:.2f}" for x in stats), *rest])
    with open(sweep_dir / "sweep.csv", "w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows([head, *csv_rows])
    lines = [head, ["---"] * len(head), *md_rows]
    text = "".join(f"| {' | '.join(map(str, line))} |\n" for line in lines)
    (sweep_dir / "sweep.md").write_text(text)


# ---------------------------------------------------------------------- command line
def run_sweep_command(args: argparse.Namespace) -> int:
    """``hrl-torch sweep``: run the sweep and print its table.

    Returns 0 when every trial finished, 1 when one failed, 130 when the sweep was interrupted
    (``--resume`` continues it). User errors raise ``ValueError`` (one line).
    """
    rows = run_sweep(
        args.domain,
        args.algo,
        parse_grid(args.grid),
        args.seeds,
        out=args.out,
        address=args.address,
        steps=args.steps,
        resume=args.resume,
        name=args.name,
        in_process=args.in_process,
        loggers=logger_names(args.logger),
    )
    sweep_dir = Path(args.out) / (args.name or f"{args.domain}__{args.algo}__sweep")
    print((sweep_dir / "sweep.md").read_text(), end="")
    print(f"sweep folder: {sweep_dir}")
    status = {row["status"] for row in rows}
    if "unfinished" in status:
        print("hrl-torch: sweep interrupted; continue it with --resume", file=sys.stderr)
        return 130
    return 1 if "error" in status else 0


def logger_names(given: list[str] | None) -> list[str]:
    """``--logger`` values (repeated or comma lists) as names; none given: TensorBoard."""
    names = [n.strip() for value in given or [] for n in value.split(",") if n.strip()]
    if given and not names:
        raise ValueError("--logger needs a name: tensorboard, csv, wandb or mlflow")
    return names or ["tensorboard"]
