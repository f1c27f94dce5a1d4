"""``hrl-torch report RUN_DIR...``: one table across runs and tasks, as rliable computes it.

The score of a seed is its final greedy evaluation in the run's ``summary.json``
(``per_seed[*].final_eval_return``, or ``final_eval_throughput`` on continuing domains;
``--metric`` names another key). Runs of one domain and algorithm pool their seeds. Two tables:

- **per task** (a domain and an algorithm): the IQM and the mean over seeds, each with its 95%
  interval of the stratified bootstrap;
- **across tasks** (per algorithm, over the domains it ran on): scores normalized by each
  domain's reference (``--reference DOMAIN=VALUE``, else the run's ``threshold``):
  ``1 + (score - reference) / |reference|``, which is ``score / reference`` for a positive one
  and 1 at the reference; then the IQM, the mean and the optimality gap
  (``1 - mean(min(score, 1))``: how far below the reference), each with its interval.
  rliable needs as many runs of every task: the first ``n`` seeds of each are used, ``n`` the
  fewest, and the table says so.

Every statistic is ``rliable.library.get_interval_estimates`` (percentile method, 2,000
replications, ``np.random.seed(seed)`` first; NumPy's global generator is restored after) with
``rliable.metrics``: the ``track`` extra. The plots and sweep tables use the same estimator
(``hrl_torch.common.stats``). The tables are printed and written to ``OUT/report.md`` and
``OUT/report.csv`` (default ``OUT``: ``report/`` in the folder that holds the run folders).
"""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import os
from pathlib import Path

import numpy as np

from hrl_torch.common.stats import REPS

INSTALL = "pip install 'hrl-torch[track]'"
CSV_HEAD = ("table", "domain", "algo", "statistic", "value", "low", "high", "seeds", "tasks")


def find_runs(paths: list[str]) -> list[tuple[Path, dict]]:
    """Every finished run folder at or under ``paths``, with its ``summary.json``."""
    runs = []
    for given in paths:
        path = Path(given)
        if not path.is_dir():
            raise ValueError(f"{given}: no such folder")
        found = [path / "summary.json"] if (path / "summary.json").is_file() else []
        found = found or sorted(path.rglob("summary.json"))
        if not found:
            raise ValueError(f"{given}: no run folder (summary.json) in it or below it")
        for file in found:
            try:
                summary = json.loads(file.read_text())
            except (OSError, ValueError) as err:
                raise ValueError(f"{file}: not a readable summary ({err})") from None
            if summary.get("status") == "finished" and summary.get("per_seed"):
                runs.append((file.parent, summary))
    if not runs:
        raise ValueError("no finished run among the folders given")
    return runs


def scores_by_task(runs, metric: str | None) -> dict[tuple[str, str], np.ndarray]:
    """``{(domain, algo): per-seed scores}``, runs of one task pooled (``ValueError``)."""
    out: dict[tuple[str, str], list[float]] = {}
    for run_dir, summary in runs:
        per_seed = summary["per_seed"]
        key = metric or next(
            (k for k in ("final_eval_throughput", "final_eval_return") if k in per_seed[0]), None
        )
        if key is None or key not in per_seed[0]:
            raise ValueError(f"{run_dir}: summary.json has no per-seed {metric!r}; it has "
                             f"{', '.join(sorted(per_seed[0]))}")  # fmt: skip
        values = [math.nan if r[key] is None else float(r[key]) for r in per_seed]
        out.setdefault((summary["domain"], summary["algo"]), []).extend(values)
    return {task: np.array(v) for task, v in out.items()}


def references(runs, given: list[str]) -> dict[str, float]:
    """Each domain's reference: ``--reference DOMAIN=VALUE``, else its runs' ``threshold``."""
    out = {}
    for _, summary in runs:
        if summary.get("threshold") is not None:
            out.setdefault(summary["domain"], float(summary["threshold"]))
    for item in given:
        name, sep, text = item.partition("=")
        try:
            value = float(text) if sep and name.strip() else None
        except ValueError:
            value = None
        if value is None:
            raise ValueError(f"--reference {item!r}: expected DOMAIN=NUMBER, e.g. taxi=7.5")
        if not math.isfinite(value) or value == 0:
            raise ValueError(f"--reference {item!r}: a reference must be a finite non-zero number")
        out[name.strip()] = float(value)
    return out


def normalized(scores: np.ndarray, reference: float) -> np.ndarray:
    """``1 + (score - reference) / |reference|``: 1 at the reference, higher is better.

    For a positive reference this is ``score / reference``; a negative one (a return of
    penalties) keeps the order, where dividing by it would turn it round.
    """
    return 1 + (scores - reference) / abs(reference)


def interval_estimates(scores: np.ndarray, stats: tuple[str, ...], reps: int, seed: int):
    """Point estimates and 95% intervals (rliable) of ``stats`` on ``scores [runs, tasks]``."""
    from rliable import library, metrics

    funcs = {
        "IQM": metrics.aggregate_iqm,
        "mean": metrics.aggregate_mean,
        "optimality gap": metrics.aggregate_optimality_gap,
    }

    def func(x):
        return np.array([funcs[name](x) for name in stats])

    state = np.random.get_state()
    try:
        np.random.seed(seed)  # rliable draws from NumPy's global generator
        points, intervals = library.get_interval_estimates({"s": scores}, func, reps=reps)
    finally:
        np.random.set_state(state)
    return points["s"], intervals["s"]


def report_rows(scores: dict, refs: dict, reps: int = REPS, seed: int = 0) -> tuple[list, list]:
    """The rows of both tables (``CSV_HEAD`` fields) and notes on what was left out."""
    rows, notes = [], []
    for (domain, algo), values in sorted(scores.items()):
        finite = values[np.isfinite(values)]
        if finite.size < len(values):
            notes.append(f"{domain} / {algo}: {len(values) - finite.size} seeds without a score")
        if finite.size == 0:
            continue
        points, ci = interval_estimates(finite[:, None], ("IQM", "mean"), reps, seed)
        for k, stat in enumerate(("IQM", "mean")):
            rows.append(("task", domain, algo, stat, points[k], ci[0, k], ci[1, k], finite.size, 1))
    for algo in sorted({a for _, a in scores}):
        domains = sorted(d for d, a in scores if a == algo)
        missing = [d for d in domains if d not in refs]
        if missing:
            notes.append(f"{algo}: no reference for {', '.join(missing)} (--reference "
                         "DOMAIN=VALUE): not aggregated across tasks")  # fmt: skip
            continue
        columns = [normalized(scores[(d, algo)], refs[d]) for d in domains]
        columns = [c[np.isfinite(c)] for c in columns]
        n = min(len(c) for c in columns)
        if n == 0:
            continue
        if any(len(c) > n for c in columns):
            notes.append(f"{algo}: the first {n} seeds of each domain aggregated (rliable needs "
                         "as many runs of every task)")  # fmt: skip
        matrix = np.stack([c[:n] for c in columns], axis=1)
        stats = ("IQM", "mean", "optimality gap")
        points, ci = interval_estimates(matrix, stats, reps, seed)
        for k, stat in enumerate(stats):
            rows.append(("all", "", algo, stat, points[k], ci[0, k], ci[1, k], n, len(domains)))
    return rows, notes


def markdown(rows, notes, refs: dict, metric: str | None, reps: int) -> str:
    """Both tables as markdown: a statistic is ``value [low, high]``."""
    cell = {(r[0], r[1], r[2], r[3]): f"{r[4]:.4g} [{r[5]:.4g}, {r[6]:.4g}]" for r in rows}
    seeds = {(r[0], r[1], r[2]): r[7] for r in rows}
    what = metric or "final greedy evaluation"
    lines = [f"Per task: {what} over seeds; IQM and mean with 95% stratified-bootstrap "
             f"intervals (rliable, {reps:,} replications)", "",
             "| domain | algorithm | seeds | IQM [95% CI] | mean [95% CI] |",
             "|---|---|---|---|---|"]  # fmt: skip
    for table, domain, algo in sorted(seeds):
        if table == "task":
            n = seeds[(table, domain, algo)]
            lines.append(f"| {domain} | {algo} | {n} | {cell[(table, domain, algo, 'IQM')]} | "
                         f"{cell[(table, domain, algo, 'mean')]} |")  # fmt: skip
    algos = sorted({r[2] for r in rows if r[0] == "all"})
    if algos:
        shown = ", ".join(f"{d} {v:g}" for d, v in sorted(refs.items()))
        lines += ["", f"Across tasks: 1 + (score - reference) / |reference| ({shown})", "",
                  "| algorithm | tasks | seeds per task | IQM [95% CI] | mean [95% CI] | "
                  "optimality gap [95% CI] |", "|---|---|---|---|---|---|"]  # fmt: skip
        for algo in algos:
            tasks = next(r[8] for r in rows if r[0] == "all" and r[2] == algo)
            parts = [cell[("all", "", algo, s)] for s in ("IQM", "mean", "optimality gap")]
            lines.append(f"| {algo} | {tasks} | {seeds[('all', '', algo)]} | "
                         f"{' | '.join(parts)} |")  # fmt: skip
    lines += [""] + [f"note: {n}" for n in notes] if notes else []
    return "\n".join(lines).rstrip() + "\n"


def run_report_command(args) -> int:
    """``hrl-torch report``: print the tables, write ``report.md`` and ``report.csv``."""
    if importlib.util.find_spec("rliable") is None:
        raise ValueError(f"report needs rliable, which is not installed: {INSTALL}")
    runs = find_runs(args.run_dirs)
    scores = scores_by_task(runs, args.metric)
    refs = references(runs, args.reference)
    rows, notes = report_rows(scores, refs, reps=args.reps, seed=args.seed)
    text = markdown(rows, notes, refs, args.metric, args.reps)
    parents = [str(run_dir.resolve().parent) for run_dir, _ in runs]
    out = Path(args.out) if args.out else Path(os.path.commonpath(parents)) / "report"
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.md").write_text(text)
    with open(out / "report.csv", "w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows([CSV_HEAD, *rows])
    print(text, end="")
    print(f"written: {out / 'report.md'}, {out / 'report.csv'}")
    return 0
