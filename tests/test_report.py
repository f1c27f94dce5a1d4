"""``hrl-torch report`` and the one estimator (IQM, rliable's stratified bootstrap) everywhere.

The slow tests train two domains x two algorithms for real and compare the report with
rliable's numbers on the same scores; the fast ones check the estimator's replica, the ranks
of the sweep tables and the report's input errors.
"""

import csv
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from hrl_torch.common.stats import aggregate_iqm, aggregate_mean, bootstrap_interval, iqm
from hrl_torch.runs.cli import main
from hrl_torch.runs.sweep import assign_ranks, seed_statistics

needs_rliable = pytest.mark.skipif(
    importlib.util.find_spec("rliable") is None, reason="the track extra is not installed"
)


def test_the_bootstrap_resamples_runs_within_each_task():
    scores = np.array([[1.0, 10.0], [1.0, 10.0], [1.0, 10.0]])  # each task's runs agree
    point, lo, hi = bootstrap_interval(scores, aggregate_mean, reps=500)
    assert point[0] == lo[0] == hi[0] == 5.5  # mixing tasks would widen it
    x = np.array([[0.0], [1.0], [2.0], [3.0], [100.0]])
    point, lo, hi = bootstrap_interval(x, reps=500, seed=3)
    assert point[0] == iqm(x) == 2.0 and lo[0] < 2.0 < hi[0] <= 100.0
    again = bootstrap_interval(x, reps=500, seed=3)
    assert again[1][0] == lo[0] and again[2][0] == hi[0]  # the seed fixes the draws


def test_sweep_rows_rank_by_iqm_and_equal_scores_share_a_rank():
    rows = [
        {"name": "a", **seed_statistics(np.array([1.0, 1.0, 1.0, 1.0]))},
        {"name": "b", **seed_statistics(np.array([5.0, 5.0, 5.0, 5.0]))},
        {"name": "c", **seed_statistics(np.array([5.0, 5.0, 5.0, 5.0]))},
        {"name": "d", **seed_statistics(np.array([0.0, 6.0, 6.0, 100.0]))},  # IQM 6, mean 28
        {"name": "e", **seed_statistics(np.array([np.nan, np.nan]))},
    ]
    ranked = assign_ranks(rows)
    assert [(r["name"], r["rank"]) for r in ranked] == [
        ("d", 1), ("b", 2), ("c", 2), ("a", 4), ("e", 5)
    ]  # fmt: skip
    assert ranked[0]["iqm"] == 6.0 and ranked[0]["mean"] == 28.0
    assert ranked[0]["iqm_low"] <= 6.0 <= ranked[0]["iqm_high"]


def test_report_input_errors_are_one_line(tmp_path, capsys, monkeypatch):
    assert main(["report", str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip().endswith("nope: no such folder")
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("no run folder (summary.json) in it or below it")
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "rliable" else real(name, *a)
    )
    assert main(["report", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == (
        "hrl-torch: error: report needs rliable, which is not installed: "
        "pip install 'hrl-torch[track]'"
    )


TASKS = [("taxi", "maxq-q"), ("taxi", "q"), ("four-rooms", "maxq-q"), ("four-rooms", "q")]


@pytest.fixture(scope="module")
def four_runs(tmp_path_factory):
    """Two domains x two algorithms, four seeds each, trained for real (a few thousand steps)."""
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, run_experiment

    out = tmp_path_factory.mktemp("runs")
    for domain, algo in TASKS:
        opts = RunOptions(seeds=[0, 1, 2, 3], steps=3000, envs_per_learner=16, eval_every=0,
                          eval_episodes=5, out=str(out), progress=False,
                          tensorboard=False)  # fmt: skip
        run_experiment(registry.get(domain), algo, opts)
    return out


def rliable_estimates(scores: np.ndarray, funcs) -> tuple[np.ndarray, np.ndarray]:
    from rliable import library

    np.random.seed(0)
    points, intervals = library.get_interval_estimates(
        {"x": scores}, lambda x: np.array([f(x) for f in funcs]), reps=2000
    )
    return points["x"], intervals["x"]


@pytest.mark.slow
@needs_rliable
def test_report_prints_rliable_s_iqm_and_intervals_on_two_domains_x_two_algorithms(
    four_runs, capsys
):
    from rliable import metrics

    assert main(["report", str(four_runs)]) == 0
    printed = capsys.readouterr().out
    with open(four_runs / "report" / "report.csv", newline="") as f:
        rows = {(r["table"], r["domain"], r["algo"], r["statistic"]): r for r in csv.DictReader(f)}
    assert printed.startswith((four_runs / "report" / "report.md").read_text())
    scores, refs = {}, {}
    for path in four_runs.glob("*/summary.json"):
        summary = json.loads(path.read_text())
        task = (summary["domain"], summary["algo"])
        scores[task] = np.array([r["final_eval_return"] for r in summary["per_seed"]])
        refs[summary["domain"]] = summary["threshold"]
    assert sorted(scores) == sorted(TASKS) and len({len(np.unique(s)) for s in scores.values()}) > 1
    for (domain, algo), values in scores.items():
        funcs = [metrics.aggregate_iqm, metrics.aggregate_mean]
        points, ci = rliable_estimates(values[:, None], funcs)
        for k, stat in enumerate(("IQM", "mean")):
            row = rows[("task", domain, algo, stat)]
            got = [float(row[c]) for c in ("value", "low", "high")]
            assert got == [points[k], ci[0, k], ci[1, k]]  # the same numbers, not close ones
        cell = f"{points[0]:.4g} [{ci[0, 0]:.4g}, {ci[1, 0]:.4g}]"
        assert f"| {domain} | {algo} | 4 | {cell} |" in printed
    for algo in ("maxq-q", "q"):
        matrix = np.stack([1 + (scores[(d, algo)] - refs[d]) / abs(refs[d])
                           for d in ("four-rooms", "taxi")], axis=1)  # fmt: skip
        funcs = [metrics.aggregate_iqm, metrics.aggregate_mean, metrics.aggregate_optimality_gap]
        points, ci = rliable_estimates(matrix, funcs)
        for k, stat in enumerate(("IQM", "mean", "optimality gap")):
            row = rows[("all", "", algo, stat)]
            assert [float(row[c]) for c in ("value", "low", "high")] == [points[k], *ci[:, k]]
        cell = f"{points[0]:.4g} [{ci[0, 0]:.4g}, {ci[1, 0]:.4g}]"
        assert f"| {algo} | 2 | 4 | {cell} |" in printed


@pytest.mark.slow
@needs_rliable
def test_the_plots_and_sweeps_estimator_is_rliable_s(four_runs):
    rng = np.random.default_rng(5)
    for scores in (rng.normal(size=(7, 3)), rng.integers(0, 4, size=(5, 1)).astype(float)):
        for func in (aggregate_iqm, aggregate_mean):
            from rliable import metrics

            theirs = {aggregate_iqm: metrics.aggregate_iqm, aggregate_mean: metrics.aggregate_mean}
            points, ci = rliable_estimates(scores, [theirs[func]])
            point, lo, hi = bootstrap_interval(scores, func)
            np.testing.assert_allclose([point[0], lo[0], hi[0]], [points[0], *ci[:, 0]],
                                       rtol=1e-12, atol=1e-12)  # fmt: skip
    summary = json.loads(next(Path(four_runs).glob("taxi__q__*/summary.json")).read_text())
    values = np.array([r["final_eval_return"] for r in summary["per_seed"]])
    row = seed_statistics(values)
    points, ci = rliable_estimates(values[:, None], [aggregate_iqm])
    assert row["iqm"] == pytest.approx(points[0], abs=1e-9)
    assert [row["iqm_low"], row["iqm_high"]] == pytest.approx(list(ci[:, 0]), abs=1e-9)
