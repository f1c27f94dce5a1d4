"""Compare runs: one PNG with every algorithm's curve, and a markdown table of their summaries."""

from __future__ import annotations

import argparse
import statistics
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import torch

from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, run_experiment
from hrl_torch.runs.plots import axis_label, draw_references, draw_seeds
from hrl_torch.training.runlog import read_curves


def compare_plot(
    runs: dict[str, Path],
    metric: str,
    path: Path,
    title: str = "",
    reference: dict[str, float] | None = None,
    ylim: tuple[float, float] | None = None,
) -> Path:
    """Every labelled run folder's seeds, IQM and 95% bootstrap interval of ``metric``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label, run_dir in runs.items():
        steps, curves = read_curves(Path(run_dir) / "progress.csv", metric)
        if curves:
            draw_seeds(ax, steps, np.stack(list(curves.values())), label)
    draw_references(ax, reference)
    if ylim:
        ax.set_ylim(*ylim)
    ax.set_xlabel("env steps per learner (seed)")
    ax.set_ylabel(axis_label(metric))
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def median_or_none(values: Sequence[float | None]) -> float | None:
    """Median of the values that are not ``None`` (``None`` if there are none)."""
    present = [v for v in values if v is not None]
    return statistics.median(present) if present else None


def summary_row(label: str, summary: dict) -> str:
    """One markdown row: seeds reaching the threshold, median steps, final return, speed."""
    per_seed = summary["per_seed"]
    hits = [r["steps_to_threshold"] for r in per_seed]
    finals = [r["final_eval_return"] for r in per_seed]
    threshold = summary.get("threshold")
    at_end = sum(f >= threshold for f in finals) if threshold is not None else "-"
    med = median_or_none(hits)
    return (
        f"| {label} | {sum(h is not None for h in hits)}/{len(hits)} | "
        f"{'-' if med is None else f'{med:,.0f}'} | {at_end}/{len(finals)} | "
        f"{statistics.mean(finals):.2f} | {summary['train_seconds']:.1f} | "
        f"{summary['env_steps_per_second']:,.0f} |"
    )


TABLE_HEADER = (
    "| algorithm | seeds reaching threshold | median env steps to threshold | seeds above "
    "threshold at the end | mean final return | train s (all seeds) | env steps/s |\n"
    "|---|---|---|---|---|---|---|"
)


def mean_sd(values: Sequence[float], digits: int = 1) -> str:
    """``mean ± sd`` of ``values`` (NaN values left out; ``n/a`` when none is left)."""
    values = [v for v in values if v == v]
    if not values:
        return "n/a"
    sd = statistics.stdev(values) if len(values) > 1 else 0.0
    return f"{statistics.mean(values):.{digits}f} ± {sd:.{digits}f}"


def run_variant(
    domain_name: str, algo: str, env_options: dict, opts: RunOptions, cache: dict
) -> Path:
    """One population run of ``algo`` with its env options updated by ``env_options``.

    Runs with the same algorithm and options are made once per ``cache`` (a figure script
    shares them between figures).
    """
    key = (domain_name, algo, tuple(sorted((k, repr(v)) for k, v in env_options.items())))
    if key not in cache:
        domain = registry.get(domain_name)
        spec = domain.algos[algo]
        spec = replace(spec, env_options={**spec.env_options, **env_options})
        domain = replace(domain, algos={**domain.algos, algo: spec})
        cache[key] = run_experiment(domain, algo, opts)[0]
    return cache[key]


def figure_cli(description: str, figures: Sequence[str], figure) -> None:
    """The command line of a figure script: ``--seeds --steps --out --only``.

    Calls ``figure(name, args, cache)`` for every chosen figure and prints what it returns.
    """
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--out", default="runs")
    parser.add_argument("--only", nargs="*", default=list(figures), choices=list(figures))
    args = parser.parse_args()
    torch.set_num_threads(1)
    cache: dict = {}
    for name in args.only:
        print(figure(name, args, cache), flush=True)
