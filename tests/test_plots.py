"""Plots: IQM and bootstrap intervals inside the seeds' range, labels, one point, references."""

import csv

import numpy as np

from hrl_torch.runs.plots import axis_label, iqm, iqm_interval, plot_curves


def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm(np.array([0.0, 1.0, 2.0, 3.0, 100.0])) == 2.0  # drops 0 and 100
    assert iqm(np.array([4.0, 6.0])) == 5.0  # too few to trim


def test_the_interval_stays_within_what_the_seeds_reached():
    # four seeds at the optimum and one collapsed: a mean +- t interval crosses the optimum
    matrix = np.array([[7.9, 7.93], [7.9, 7.93], [7.9, 7.93], [7.9, 7.93], [-50.0, -50.0]])
    center, lo, hi = iqm_interval(matrix)
    assert np.all(hi <= 7.93 + 1e-12) and np.all(lo >= -50.0)
    assert np.allclose(center, [7.9, 7.93])
    mean, sd = matrix.mean(0), matrix.std(0, ddof=1)
    assert np.all(mean + 2.776 * sd / np.sqrt(5) > 7.93)  # what the old t-band drew


def test_labels_name_the_quantity_and_unit():
    assert axis_label("charts/eval_return") == "greedy return per episode"
    assert axis_label("charts/throughput", "assemblies per 1,000 s") == (
        "training throughput (assemblies per 1,000 s)"
    )
    assert axis_label("charts/eval_throughput", "x") == "greedy throughput (x)"


def _progress(path, points):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "seed", "metric", "value"])
        for step, seed, value in points:
            w.writerow([step, seed, "charts/eval_return", value])


def test_one_evaluation_point_and_many_both_draw(tmp_path):
    _progress(tmp_path / "one.csv", [(100, s, v) for s, v in enumerate([1.0, 2.0, 3.0])])
    [one] = plot_curves(tmp_path / "one.csv", ["charts/eval_return"], tmp_path, reference={"a": 2})
    assert one.stat().st_size > 5_000
    many = [(step, s, step * 0.01 + s) for step in (100, 200, 300) for s in range(3)]
    _progress(tmp_path / "many.csv", many)
    (tmp_path / "m").mkdir()
    [path] = plot_curves(tmp_path / "many.csv", ["charts/eval_return"], tmp_path / "m")
    assert path.exists()
