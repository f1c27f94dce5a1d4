"""Learning-curve plots a reader can publish: every seed, the IQM and a bootstrap interval.

Across seeds we draw each seed's curve thinly, their interquartile mean (IQM: the mean of the
middle half, robust to one collapsed seed) and a 95% percentile-bootstrap interval of that IQM
over seeds, as ``rliable`` recommends (Agarwal et al. 2021). Both stay inside the range the
seeds reached, so a band never crosses a bound the metric cannot cross (a mean +- t interval
did). A curve of one evaluation is drawn as points with the interval as error bars.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hrl_torch.common import stats

BOOTSTRAP_SAMPLES = stats.REPS
LABELS = {
    "charts/eval_return": "greedy return per episode",
    "charts/episode_return": "training return per episode (exploring)",
    "charts/eval_success": "greedy success rate",
    "charts/episode_success": "training success rate (exploring)",
    "charts/episode_length": "training episode length (steps)",
    "charts/eval_reward_rate": "greedy reward per unit of time",
    "charts/reward_rate": "training reward per unit of time (exploring)",
    "charts/eval_wait": "greedy waiting time per delivered passenger (steps)",
    "charts/wait": "training waiting time per delivered passenger (steps)",
    "charts/communication_rate": "share of decisions made under Com",
}
_STYLES = (("--", "black"), (":", "tab:red"), ("-.", "tab:green"), ((0, (5, 1)), "tab:purple"))


def axis_label(metric: str, unit: str | None = None) -> str:
    """The y-axis label of ``metric``: words and unit, not the raw tag."""
    if unit is not None:
        kind = "training" if "/eval_" not in metric else "greedy"
        return f"{kind} throughput ({unit})"
    return LABELS.get(metric, metric.split("/")[-1].replace("_", " "))


def iqm(values: np.ndarray, axis: int = 0) -> np.ndarray:
    """Interquartile mean along ``axis`` (``scipy.stats.trim_mean(values, 0.25)``), NaN-free."""
    return stats.iqm(values, axis)


def iqm_interval(
    matrix: np.ndarray, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per column of ``matrix [seeds, points]``: IQM and its 95% bootstrap interval (lo, hi).

    The interval is rliable's (``hrl_torch.common.stats.bootstrap_interval``: the same numbers
    as ``rliable.library.get_interval_estimates`` on that column's seeds after
    ``np.random.seed(seed)``). Seeds missing a point (NaN), or whose value there is infinite
    (a return that overflowed; summary.json names it), are left out of that point; a point no
    seed has is NaN.
    """
    center, lo, hi = (np.full(matrix.shape[1], np.nan) for _ in range(3))
    for j in range(matrix.shape[1]):
        x = matrix[:, j][np.isfinite(matrix[:, j])]
        if x.size == 0:
            continue
        point, low, high = stats.bootstrap_interval(x[:, None], reps=samples, seed=seed)
        center[j], lo[j], hi[j] = point[0], low[0], high[0]
    return center, lo, hi


def draw_seeds(ax, steps: np.ndarray, matrix: np.ndarray, label: str, color=None) -> None:
    """Each seed thinly, the IQM and its interval (as error bars for a single point)."""
    center, lo, hi = iqm_interval(matrix)
    n = matrix.shape[0]
    if steps.size == 1:
        bars = ax.errorbar(
            steps,
            center,
            yerr=[center - lo, hi - center],
            fmt="o",
            capsize=4,
            color=color,
            label=f"{label}: IQM of {n} seeds, 95% interval",
        )
        ax.plot(np.repeat(steps, n), matrix[:, 0], "x", color=bars[0].get_color(), alpha=0.5)
        return
    line = ax.plot(steps, center, color=color, lw=1.8, label=f"{label}: IQM of {n} seeds")[0]
    ax.fill_between(
        steps, lo, hi, color=line.get_color(), alpha=0.2, lw=0, label="95% bootstrap interval"
    )
    for row in matrix:
        ax.plot(steps, row, color=line.get_color(), lw=0.6, alpha=0.35)


def draw_references(ax, reference: dict[str, float] | None) -> None:
    """Each reference value as its own named, distinct horizontal line."""
    for k, (name, value) in enumerate((reference or {}).items()):
        style, color = _STYLES[k % len(_STYLES)]
        label = name if f"{value:g}" in name else f"{name} ({value:g})"
        ax.axhline(value, ls=style, c=color, lw=1.1, label=label)


def plot_curves(
    csv_path: Path,
    metrics: Sequence[str],
    out_dir: Path,
    title: str = "",
    reference: dict[str, float] | None = None,
    units: dict[str, str] | None = None,
) -> list[Path]:
    """One PNG per metric of a run's ``progress.csv``: seeds, IQM, interval, references."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hrl_torch.training.runlog import read_curves

    paths = []
    for metric in metrics:
        steps, curves = read_curves(csv_path, metric)
        if not curves:
            continue
        matrix = np.stack(list(curves.values()))
        if np.all(np.isnan(matrix)):
            continue
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        draw_seeds(ax, steps, matrix, "this run")
        draw_references(ax, reference)
        ax.set_xlabel("env steps per learner (seed)")
        label = axis_label(metric, (units or {}).get(metric))
        ax.set_ylabel("\n".join(textwrap.wrap(label, 42)), fontsize=9)
        ax.set_title(title or metric, fontsize=10)
        ax.legend(fontsize=7, loc="best")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        path = out_dir / f"{metric.replace('/', '_')}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths
