"""One estimator everywhere: IQM and rliable's stratified-bootstrap interval, in NumPy.

Plots, sweep tables and ``hrl-torch report`` state a score as its interquartile mean (IQM)
with a 95% percentile interval of the stratified bootstrap over runs (Agarwal et al. 2021).
``hrl-torch report`` calls the ``rliable`` package itself (the ``track`` extra); the plots and
sweep tables, which must work without it, call ``bootstrap_interval`` here, which gives the
numbers ``rliable.library.get_interval_estimates(method="percentile")`` gives after
``np.random.seed(seed)``: rliable draws each replication's run indices with
``np.random.choice(runs, (runs, tasks))`` from NumPy's global generator, so a ``RandomState``
of the same seed draws the same indices (``tests/test_report.py`` checks the equality).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: bootstrap replications (rliable's examples use 2,000 and more)
REPS = 2_000


def iqm(values: np.ndarray, axis: int | None = None) -> np.ndarray:
    """Interquartile mean (``scipy.stats.trim_mean(values, 0.25, axis)``; all values: ``None``)."""
    if axis is None:
        values, axis = np.ravel(values), 0
    n = values.shape[axis]
    cut = int(0.25 * n)
    ordered = np.sort(values, axis=axis)
    return np.take(ordered, range(cut, n - cut), axis=axis).mean(axis=axis)


def aggregate_iqm(scores: np.ndarray) -> float:
    """IQM over all runs and tasks of ``scores [runs, tasks]`` (``rliable.metrics``)."""
    return float(iqm(scores))


def aggregate_mean(scores: np.ndarray) -> float:
    """Mean over tasks of each task's mean over runs (``rliable.metrics.aggregate_mean``)."""
    return float(np.mean(np.mean(scores, axis=0)))


def optimality_gap(scores: np.ndarray, gamma: float = 1.0) -> float:
    """``gamma - mean(min(scores, gamma))`` (``rliable.metrics.aggregate_optimality_gap``)."""
    return float(gamma - np.mean(np.minimum(scores, gamma)))


def bootstrap_interval(
    scores: np.ndarray,
    func: Callable[[np.ndarray], np.ndarray] = aggregate_iqm,
    reps: int = REPS,
    size: float = 0.95,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``func(scores)`` and its stratified-bootstrap percentile interval ``(point, lo, hi)``.

    Args:
        scores: ``[runs, tasks]`` (a run per seed; every task has as many runs).
        func: a statistic of a ``[runs, tasks]`` matrix: a number or a 1-D array.
        reps: bootstrap replications.
        size: the interval's coverage.
        seed: the seed of the draws (rliable's after ``np.random.seed(seed)``).
    """
    scores = np.asarray(scores, dtype=float)
    if scores.ndim != 2 or scores.shape[0] == 0:
        raise ValueError(f"scores must be [runs, tasks] with a run, got shape {scores.shape}")
    runs, tasks = scores.shape
    rows = np.random.RandomState(seed).choice(runs, (reps, runs, tasks))  # rliable's draws
    resampled = scores[rows, np.arange(tasks)]  # each task's runs resampled (stratified)
    if func is aggregate_iqm:  # all replications at once
        stats = iqm(resampled.reshape(reps, -1), axis=1)[:, None]
    else:
        stats = np.array([np.atleast_1d(func(r)) for r in resampled], dtype=float)
    alpha = 100 * (1 - size) / 2
    lo, hi = np.percentile(stats, [alpha, 100 - alpha], axis=0)
    return np.atleast_1d(np.asarray(func(scores), dtype=float)), lo, hi
