"""Run folders: TensorBoard events, a CSV of every logged point, PNG curves and ``summary.json``.

Layout of ``runs/{domain}__{algo}__{timestamp}/``::

    tb/seed_<s>/      TensorBoard events, one run per seed (tags ``charts/``, ``hrl/<subtask>/``,
                      ``losses/<subtask>/``, ``perf/``; hyperparameters once as text)
    progress.csv      long format, one row per (step, seed, metric): step,seed,metric,value
    eval_episodes.csv every greedy evaluation episode: step, seed, episode, return, length,
                      success, truncated, start (its reset observation), the root's decisions,
                      partial (1: a signal cut that evaluation short), loop (the cycle of
                      observations an episode at the step limit repeated)
    <metric>.png      mean and 95% interval over seeds of each curve metric
    summary.json      per-seed final metrics, env steps, wall-clock, env-steps/s
    checkpoint.pt     the latest checkpoint (when checkpointing is on)
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
import subprocess
import sys
import time
import types
import warnings
from collections.abc import Sequence
from dataclasses import asdict, is_dataclass
from pathlib import Path

import numpy as np

from hrl_torch.common.safe_files import RunFolderError, open_own, replace_file, write_own


@functools.cache
def code_version() -> dict:
    """hrl-torch's version, and the git commit it runs from with a dirty flag (or ``None``)."""
    from hrl_torch import __version__

    root = Path(__file__).resolve().parents[2]  # hrl_torch/training/runlog.py
    out = {"version": __version__, "commit": None, "dirty": None}
    try:
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        if head.returncode == 0:
            status = subprocess.run(
                ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                capture_output=True,
                text=True,
                timeout=10,
            )
            out["commit"] = head.stdout.strip()
            out["dirty"] = bool(status.stdout.strip()) if status.returncode == 0 else None
    except (OSError, subprocess.TimeoutExpired):  # no git here: the version alone
        pass
    return out


def settings_of(obj) -> dict:
    """An object's class and its plain settings (numbers, strings, flags, schedules)."""
    out: dict = {"class": type(obj).__name__}
    for key, value in vars(obj).items():
        if key.startswith("_") or key == "training":  # private state; nn.Module's mode flag
            continue
        if isinstance(value, (bool, int, float, str)):
            out[key] = value
        elif is_dataclass(value):  # a schedule (Linear(...)) or an option group (PGConfig)
            out[key] = repr(value)
    return out


#: callables logged by their name (a class, a function); any other by ``repr``
_NAMED = (type, types.FunctionType, types.BuiltinFunctionType, types.MethodType)


def hparams_of(**parts) -> dict:
    """Flatten dataclasses and plain values into one hyperparameter dict for logging."""
    out = {}
    for name, value in parts.items():
        if is_dataclass(value):
            out.update({f"{name}.{k}": v for k, v in asdict(value).items()})
        elif callable(value):
            out[name] = value.__name__ if isinstance(value, _NAMED) else repr(value)
        else:
            out[name] = value
    return out


#: the metrics the HParams tab shows beside the settings (each run's own scalars of that tag)
HPARAMS_METRICS = ("charts/eval_return", "charts/eval_success", "charts/eval_throughput")


def flat_hparams(hparams: dict, prefix: str = "") -> dict:
    """``hparams`` with nested dicts flattened to dotted names, as TensorBoard takes them.

    Numbers, strings and bools stay as they are; anything else becomes its JSON text.
    """
    out = {}
    for key, value in hparams.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flat_hparams(value, f"{name}."))
        elif isinstance(value, (bool, int, float, str)):
            out[name] = value
        else:
            out[name] = json.dumps(value, default=json_default)
    return out


def tensorboard_hparams(hparams: dict) -> tuple:
    """The HParams plugin's three summaries for one TensorBoard run.

    Its settings (``flat_hparams``) and its metrics (``HPARAMS_METRICS``), written into the
    run itself: the HParams tab lists every seed of every run and sweep trial with its
    settings beside its evaluation scalars.
    """
    from torch.utils.tensorboard.summary import hparams as hparams_summaries

    return hparams_summaries(flat_hparams(hparams), dict.fromkeys(HPARAMS_METRICS, 0.0))


def make_run_dir(root: str | Path, domain: str, algo: str) -> Path:
    """A new, unique ``root/{domain}__{algo}__{timestamp}`` folder, made by this call.

    Each name is tried with one ``mkdir`` that fails if anything (a folder, a file, a dangling
    link) is there, then the next name: two processes or threads never get the same folder.

    Raises:
        RunFolderError: the folder cannot be made (its name too long, no space, no rights).
    """
    stamp = time.strftime("%Y%m%d-%H%M%S")
    base = Path(root) / f"{domain}__{algo}__{stamp}"
    try:
        Path(root).mkdir(parents=True, exist_ok=True)
        for k in range(100_000):
            path = base if k == 0 else Path(f"{base}-{k}")
            try:
                path.mkdir()
                return path
            except FileExistsError:
                continue
    except OSError as err:
        what = err.strerror or type(err).__name__
        raise RunFolderError(
            f"cannot make a run folder in {str(root)[:60]}{'...' if len(str(root)) > 60 else ''}"
            f" ({what}): choose a shorter or writable --out"
        ) from err
    raise RunFolderError(f"{root}: 100000 run folders named {base.name} exist; use another --out")


class RunLogger:
    """Writes scalars for every seed to TensorBoard and the CSV; draws the curves at the end.

    Args:
        run_dir: the run folder.
        seeds: the seed of each learner (one TensorBoard run each).
        hparams: logged once per seed as text, to TensorBoard's HParams tab (flattened to
            dotted names, with the seed; ``tensorboard_hparams``) and to ``hparams.json``.
        tensorboard: write TensorBoard events (needs the ``tensorboard`` package).
        trackers: other trackers through ``torchrl.record.loggers``: ``"csv"``, ``"wandb"``
            (offline), ``"mlflow"`` (a SQLite store), inside ``run_dir``
            (``hrl_torch.training.trackers``).
        resumed_at: a resumed run's checkpoint step. ``hparams.json`` keeps the original
            settings and appends this resume to its ``"resumes"``; rows logged after the step
            (by a run stopped between checkpoints) are dropped from the CSVs and
            purged from TensorBoard, so the continuation logs no step twice.
    """

    def __init__(
        self,
        run_dir: Path,
        seeds: Sequence[int],
        hparams: dict,
        tensorboard: bool = True,
        resumed_at: int | None = None,
        trackers: Sequence[str] = (),
    ) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.seeds = list(seeds)
        self.csv_path = self.run_dir / "progress.csv"
        hparams = self._record_hparams(hparams, resumed_at)
        self.episodes_path = self.run_dir / "eval_episodes.csv"
        if resumed_at is not None:
            for path in (self.csv_path, self.episodes_path):
                if path.exists():
                    _drop_rows_after(path, resumed_at)
        if not self.csv_path.exists() or self.csv_path.stat().st_size == 0:  # (0: cut at start)
            write_own(self.csv_path, PROGRESS_HEADER)
        self.writers = []
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            purge = None if resumed_at is None else resumed_at + 1
            text = "\n".join(f"    {k}: {v}" for k, v in sorted(hparams.items()))
            for s in self.seeds:
                w = SummaryWriter(str(self.run_dir / "tb" / f"seed_{s}"), purge_step=purge)
                if resumed_at is None:
                    w.add_text("hparams", text, 0)
                    for summary in tensorboard_hparams({**hparams, "seed": s}):
                        w.file_writer.add_summary(summary)
                self.writers.append(w)
        self.trackers = None
        if trackers:
            from hrl_torch.training.trackers import Trackers

            params = flat_hparams(hparams)
            try:
                self.trackers = Trackers(self.run_dir, trackers, self.seeds, params, resumed_at)
            except BaseException:
                self.close()  # the TensorBoard writers' threads stop
                raise

    def _record_hparams(self, hparams: dict, resumed_at: int | None) -> dict:
        """Write ``hparams.json``: the original's settings, plus every resume."""
        path = self.run_dir / "hparams.json"
        hparams = json.loads(json.dumps(hparams, default=json_default))  # as written: comparable
        if resumed_at is not None and path.exists():
            original = json.loads(path.read_text())
            resume = {"at_step": resumed_at, "time": time.strftime("%Y-%m-%d %H:%M:%S")}
            resume.update({k: v for k, v in hparams.items() if original.get(k) != v})
            original.setdefault("resumes", []).append(resume)
            hparams = original
        write_own(path, json.dumps(hparams, indent=2))
        return hparams

    def log(self, step: int, per_seed: dict[str, Sequence[float]]) -> None:
        """Log ``{tag: [value per seed]}`` at env step ``step`` (NaN values are skipped)."""
        rows = []
        for tag, values in per_seed.items():
            for k, seed in enumerate(self.seeds):
                v = float(values[k])
                if math.isnan(v):
                    continue
                rows.append((step, seed, tag, f"{v:.6g}"))
                if self.writers:
                    self.writers[k].add_scalar(tag, v, step)
        with open_own(self.csv_path, "a", newline="") as f:
            csv.writer(f, lineterminator="\n").writerows(rows)
        if self.trackers is not None:
            self.trackers.log(step, per_seed)

    def log_episodes(
        self,
        step: int,
        records,
        node_names: Sequence[str],
        partial: bool = False,
        loops: Sequence[str] | None = None,
    ) -> None:
        """Append one evaluation's episodes (``Trainer.evaluate_episodes``) to the CSV.

        ``eval_episodes.csv`` gets the start's fields and the root's decisions by name;
        ``partial``: a signal cut the evaluation short (its ``partial`` column is 1);
        ``loops``: per episode, the cycle an episode that hit the step limit repeated
        (``hrl_torch.training.loops``; the ``loop`` column). A file begun before a column
        existed keeps its own columns.
        """
        new = not self.episodes_path.exists() or self.episodes_path.stat().st_size == 0
        columns = EPISODE_COLUMNS if new else tuple(_header(self.episodes_path).split(","))
        rows = []
        for r in range(records.batch_size[0]):
            n = int(records["n_decisions"][r])
            names = [node_names[int(k)] for k in records["decisions"][r, :n]]
            row = {
                "step": step,
                "seed": int(records["seed"][r]),
                "episode": int(records["episode"][r]),
                "return": f"{float(records['return'][r]):.6g}",
                "length": int(records["length"][r]),
                "success": int(records["success"][r]),
                "truncated": int(records["truncated"][r]),
                "start": fields_text(records["start"][r]),
                "decisions": " ".join(names) + (" ..." if n > len(names) else ""),
                "partial": int(partial),
                "loop": loops[r] if loops else "",
            }
            rows.append(tuple(row[c] for c in columns if c in row))
        with open_own(self.episodes_path, "a", newline="") as f:
            writer = csv.writer(f, lineterminator="\n")
            if new:
                writer.writerow(EPISODE_COLUMNS)
            writer.writerows(rows)

    def close(self) -> None:
        """Flush TensorBoard files; finish the trackers' runs."""
        for w in self.writers:
            w.flush()
            w.close()
        self.writers = []
        if self.trackers is not None:
            self.trackers.close()
            self.trackers = None

    def write_summary(self, summary: dict) -> Path:
        """Write ``summary.json``: valid JSON, a non-finite number as ``null``.

        Such numbers are named under ``"not_finite"`` (``["per_seed[0].final_eval_return"]``):
        a return of ``3e38`` per step overflows to ``inf``, which JSON cannot hold.
        """
        path = self.run_dir / "summary.json"
        plain = json.loads(json.dumps(summary, default=json_default))
        clean, bad = finite_only(plain)
        if bad:
            clean["not_finite"] = bad
        write_own(path, json.dumps(clean, indent=2, allow_nan=False))
        return path


PROGRESS_HEADER = "step,seed,metric,value\n"
EPISODE_COLUMNS = (
    "step", "seed", "episode", "return", "length", "success", "truncated", "start", "decisions",
    "partial", "loop",
)  # fmt: skip


def read_episodes(run_dir: str | Path, step: int | None = None) -> list[dict]:
    """The episodes of a run folder's latest evaluation (or the one at ``step``), worst first.

    Read from ``eval_episodes.csv``, numbers parsed; the rows of an evaluation a signal cut
    short (``partial``) only where no complete evaluation was logged.
    """
    with open(Path(run_dir) / "eval_episodes.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    rows = [r for r in rows if r.get("partial") != "1"] or rows
    if not rows:
        return []
    at = max(int(r["step"]) for r in rows) if step is None else step
    out = []
    for r in rows:
        if int(r["step"]) != at:
            continue
        out.append(
            {
                **r,
                **{k: int(r[k]) for k in ("step", "seed", "episode", "length")},
                "return": float(r["return"]),
                "success": r["success"] == "1",
                "truncated": r["truncated"] == "1",
            }
        )
    return sorted(out, key=lambda r: (r["return"], r["seed"], r["episode"]))


def _header(path: Path) -> str:
    """The first line of a CSV file."""
    with open(path) as f:
        return f.readline().rstrip("\r\n")


def fields_text(td) -> str:
    """``k=v`` for every field of one observation (floats with 3 significant digits)."""
    parts = []
    named = {  # nested keys (a multi-agent start's "agents" fields) as dotted names
        key if isinstance(key, str) else ".".join(key): value
        for key, value in td.items(include_nested=True, leaves_only=True)
    }
    for name, value in sorted(named.items()):
        flat = value.flatten().tolist()
        text = ",".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in flat)
        parts.append(f"{name}={text}")
    return " ".join(parts)


def _drop_rows_after(csv_path: Path, step: int) -> None:
    """Keep the whole rows of a run's CSV logged at or before ``step`` (atomically).

    A process killed mid-write leaves a partial last row (``12,0,charts/eval_return``): it has
    no line end or too few fields, and goes with the rows after the checkpoint.
    """
    text = csv_path.read_text()
    text = text[: text.rfind("\n") + 1]  # a row without its line end was cut short
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        return
    header = rows[0]
    kept = [header, *(r for r in rows[1:] if len(r) == len(header) and _step_of(r) <= step)]
    replace_file(csv_path, lambda f: csv.writer(f, lineterminator="\n").writerows(kept))


def _step_of(row: list[str]) -> float:
    """A row's step (``inf`` for a damaged one, so that it is dropped)."""
    try:
        return int(row[0])
    except ValueError:
        return math.inf


def finite_only(value, where: str = "") -> tuple:
    """``(value with every NaN or infinite float as None, the dotted places of those)``."""
    if isinstance(value, float) and not math.isfinite(value):
        return None, [f"{where} ({value})"]
    if isinstance(value, dict):
        out, bad = {}, []
        for k, v in value.items():
            out[k], more = finite_only(v, f"{where}.{k}" if where else str(k))
            bad += more
        return out, bad
    if isinstance(value, list):
        pairs = [finite_only(v, f"{where}[{i}]") for i, v in enumerate(value)]
        return [p[0] for p in pairs], [b for p in pairs for b in p[1]]
    return value, []


def json_default(x):
    """A NumPy number as a number, a tensor as its number or list of numbers, others as text."""
    if isinstance(x, np.generic):
        return x.item()
    torch = sys.modules.get("torch")  # no tensor exists unless torch was imported
    if torch is not None and isinstance(x, torch.Tensor):
        return x.tolist()  # a per-learner value: one number per learner
    return str(x)


def read_curves(csv_path: Path, metric: str) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Steps and ``{seed: values}`` of one metric from a progress CSV (missing -> NaN).

    A row cut short by a crash (no value) is skipped.
    """
    values: dict[int, dict[int, float]] = {}
    with open(csv_path) as f:
        for row in csv.DictReader(f):
            if row["metric"] == metric and row.get("value"):
                values.setdefault(int(row["seed"]), {})[int(row["step"])] = float(row["value"])
    grid = np.array(sorted({step for d in values.values() for step in d}))
    return grid, {s: np.array([d.get(t, math.nan) for t in grid]) for s, d in values.items()}


# two-sided 95% quantiles of Student's t for 1..30 degrees of freedom
_T975 = (
    12.706,
    4.303,
    3.182,
    2.776,
    2.571,
    2.447,
    2.365,
    2.306,
    2.262,
    2.228,
    2.201,
    2.179,
    2.160,
    2.145,
    2.131,
    2.120,
    2.110,
    2.101,
    2.093,
    2.086,
    2.080,
    2.074,
    2.069,
    2.064,
    2.060,
    2.056,
    2.052,
    2.048,
    2.045,
    2.042,
)


def t_quantile_975(dof: int) -> float:
    """The 0.975 quantile of Student's t with ``dof`` degrees of freedom (1.96 above 30)."""
    if dof < 1:
        return 0.0
    return _T975[dof - 1] if dof <= len(_T975) else 1.96


def mean_ci95(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean over rows (seeds) and the half-width of a 95% t-interval, per column (NaN-aware)."""
    n = np.sum(~np.isnan(matrix), axis=0)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(matrix, axis=0)
        std = np.nanstd(matrix, axis=0, ddof=1)
    half = np.array([t_quantile_975(int(k) - 1) for k in n]) * np.nan_to_num(std)
    return mean, half / np.sqrt(np.maximum(n, 1))
