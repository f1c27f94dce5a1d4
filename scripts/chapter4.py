"""Shared by the Chapter 4 figure scripts: run each curve through the CLI, plot and tabulate.

Every curve is one ``hrl-torch train DOMAIN --algo ALGO --seeds N`` run (all seeds as one
population); its ``summary.json`` holds the per-seed throughput, its ``progress.csv`` the
curves (``charts/eval_throughput``: greedy policy, ``charts/throughput``: the training rows).
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path

import numpy as np

from hrl_torch.runs import cli
from hrl_torch.runs.report import compare_plot
from hrl_torch.training.runlog import read_curves

EVAL, TRAIN = "charts/eval_throughput", "charts/throughput"


def run_cli(domain: str, algo: str, seeds: int, out: Path, steps: int | None = None) -> Path:
    """``hrl-torch train domain --algo algo --seeds seeds``; returns the new run folder."""
    before = set(out.glob(f"{domain}__{algo}__*"))
    args = ["train", domain, "--algo", algo, "--seeds", str(seeds), "--out", str(out)]
    if steps:
        args += ["--steps", str(steps)]
    if cli.main([*args, "--no-progress"]) != 0:
        raise SystemExit(f"hrl-torch {' '.join(args)} failed")
    (run,) = set(out.glob(f"{domain}__{algo}__*")) - before
    return run


def mean_curve(run: Path, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """Steps and the mean over seeds of one logged metric."""
    steps, curves = read_curves(run / "progress.csv", metric)
    return steps, np.nanmean(np.stack(list(curves.values())), axis=0)


def steps_to_reach(run: Path, metric: str, level: float) -> int | None:
    """First logged step where the seed mean of ``metric`` is at least ``level``."""
    steps, mean = mean_curve(run, metric)
    hit = np.nonzero(mean >= level)[0]
    return int(steps[hit[0]]) if len(hit) else None


def summary_of(run: Path) -> dict:
    """The run's ``summary.json``."""
    return json.loads((run / "summary.json").read_text())


def _mean_sd(values: list[float]) -> str:
    sd = statistics.stdev(values) if len(values) > 1 else 0.0
    return f"{statistics.mean(values):,.1f} ± {sd:,.1f}"


def table(runs: dict[str, Path], level: float | None = None) -> str:
    """Markdown table: final greedy and training throughput (mean ± sd over seeds), speed."""
    head = (
        "| algorithm | seeds | env steps per seed | final greedy throughput | "
        "final training throughput | steps to reach {lvl} (training, seed mean) | "
        "env steps/s (all seeds) | train s |\n|---|---|---|---|---|---|---|---|"
    ).format(lvl="-" if level is None else f"{level:,.1f}")
    rows = [head]
    for label, run in runs.items():
        s = summary_of(run)
        per = s["per_seed"]
        hit = None if level is None else steps_to_reach(run, TRAIN, level)
        rows.append(
            f"| {label} | {len(per)} | {s['env_steps_per_learner']:,} | "
            f"{_mean_sd([r['final_eval_throughput'] for r in per])} | "
            f"{_mean_sd([r['final_train_throughput'] for r in per])} | "
            f"{'-' if hit is None else f'{hit:,}'} | {s['env_steps_per_second']:,.0f} | "
            f"{s['train_seconds']:,.0f} |"
        )
    return "\n".join(rows)


def plots(runs: dict[str, Path], out: Path, title: str, reference: dict[str, float]) -> list:
    """One comparison plot per curve kind (greedy and training throughput)."""
    return [
        compare_plot(runs, EVAL, out / "eval_throughput.png", f"{title}: greedy policy", reference),
        compare_plot(
            runs, TRAIN, out / "training_throughput.png", f"{title}: while learning", reference
        ),
    ]


def write(out: Path, name: str, text: str) -> Path:
    """Write ``text`` to ``out/name`` and echo it."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / name
    path.write_text(text + "\n")
    print(text)
    return path


def agv_figure(domain: str, name: str, title: str, doc: str) -> None:
    """Figures 4.6 / 4.7: HAR, HDR, RAR and flat RVI Q-learning on ``domain``."""
    import argparse

    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=None, help="hierarchical: steps per seed")
    parser.add_argument("--flat-steps", type=int, default=None, help="RVI-Q: steps per seed")
    parser.add_argument("--out", default="runs")
    parser.add_argument("--algos", nargs="+", default=["har", "hdr", "rar", "rvi-q"])
    parser.add_argument(
        "--reuse", nargs="*", default=[], help="finished run folders to use instead of rerunning"
    )
    args = parser.parse_args()
    root = Path(args.out)
    labels = {"har": "HAR", "hdr": "HDR", "rar": "RAR", "rvi-q": "RVI-Q (flat)"}
    reused = {summary_of(Path(r))["algo"]: Path(r) for r in args.reuse}
    runs = {}
    for algo in args.algos:
        steps = args.flat_steps if algo == "rvi-q" else args.steps
        runs[labels[algo]] = reused.get(algo) or run_cli(domain, algo, args.seeds, root, steps)
    out = root / name
    plots(runs, out, title, {})
    best_flat = None
    if "RVI-Q (flat)" in runs:
        best_flat = summary_of(runs["RVI-Q (flat)"])["per_seed"]
        best_flat = 0.95 * statistics.mean(r["final_train_throughput"] for r in best_flat)
    text = "\n\n".join(
        [
            table(runs, best_flat),
            "steps-to-reach column: 95% of flat RVI-Q's final training throughput"
            if best_flat is not None
            else "",
            "\n".join(f"- {k}: `{v}`" for k, v in runs.items()),
        ]
    )
    write(out, "table.md", text)
