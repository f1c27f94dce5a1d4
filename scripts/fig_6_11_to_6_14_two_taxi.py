"""Figures 6.11-6.14: two taxis with Cooperative and COM-Cooperative HRL and their baselines.

Every curve is one population run (``hrl_torch.experiment.run_experiment``, the CLI's path)
of the ``two-taxi`` domain:

- Figures 6.11 and 6.12: throughput (passengers delivered per 5,000 steps) and average
  waiting time per passenger of selfish multi-agent HRL, Cooperative HRL, COM-Cooperative HRL
  with ComCost 0 and single-agent HRL (one taxi), passenger arrival rate 10;
- Figure 6.13: waiting time of selfish HRL and COM-Cooperative HRL (ComCost 0) at arrival
  rates 5, 10 and 20 (the text's rate: mean steps between arrivals, ``envs.two_taxi``);
- Figure 6.14: COM-Cooperative HRL with ComCost 0, 1, 5 and 10 against selfish HRL:
  throughput, waiting time and the share of decisions made communicating;
- ``loss`` (beyond the text): COM-Cooperative HRL with ComCost 0 when 0%, 50% or 100% of the
  replies are lost.

Writes per figure ``runs/fig_6_x/`` (run folders with TensorBoard, CSV, PNG, summary),
comparison plots of the training curves (mean over seeds) and ``table.md`` (final greedy and
training values, mean ± sd over seeds).

    python scripts/fig_6_11_to_6_14_two_taxi.py [--seeds 5] [--steps 200000] [--only fig_6_11 ...]
"""

from __future__ import annotations

import json
from pathlib import Path

import agents  # noqa: F401  (registers the domains)
from envs.two_taxi import MEAN_INTERARRIVAL
from hrl_torch.experiment import RunOptions
from hrl_torch.report import compare_plot, figure_cli, mean_sd, run_variant
from hrl_torch.runlog import read_curves

THROUGHPUT, WAIT, COM_RATE = "charts/throughput", "charts/wait", "charts/communication_rate"
BASE = [("selfish", {}), ("cooperative", {}), ("com-0", {}), ("single", {})]
FIGURES = {
    "fig_6_11": (BASE, [THROUGHPUT]),
    "fig_6_12": (BASE, [WAIT]),
    "fig_6_13": (
        [
            (a, rate)
            for rate in ({"mean_interarrival": 5.0}, {}, {"mean_interarrival": 20.0})
            for a in ("selfish", "com-0")
        ],
        [WAIT, THROUGHPUT],
    ),
    "fig_6_14": (
        [("selfish", {}), *((f"com-{c}", {}) for c in (0, 1, 5, 10))],
        [THROUGHPUT, WAIT, COM_RATE],
    ),
    # beyond the text: what the learned policy does when replies are lost
    "loss": (
        [("com-0", {}), ("com-0-loss50", {}), ("com-0-loss100", {})],
        [THROUGHPUT, WAIT, COM_RATE],
    ),
}


def run(algo: str, options: dict, args, out: Path, cache: dict) -> Path:
    """One population run (runs with the same algorithm and options are shared)."""
    opts = RunOptions(seeds=list(range(args.seeds)), steps=args.steps, out=str(out), progress=False)
    return run_variant("two-taxi", algo, options, opts, cache)


def label(algo: str, options: dict) -> str:
    """Curve label: the algorithm and its arrival rate (mean steps between arrivals)."""
    return f"{algo} rate {options.get('mean_interarrival', MEAN_INTERARRIVAL):g}"


def last_values(run_dir: Path, metric: str) -> list[float]:
    """The last logged value of ``metric`` per seed."""
    _, curves = read_curves(run_dir / "progress.csv", metric)
    return [float(curve[-1]) for curve in curves.values()]


def figure(name: str, args, cache: dict) -> str:
    """Run one figure's curves; plot and tabulate them."""
    curves_of, metrics = FIGURES[name]
    out = Path(args.out) / name
    rows = [
        f"### {name}",
        "",
        "| curve | greedy throughput | training throughput | greedy wait | training wait "
        "| communication rate | train s |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    curves = {}
    for algo, options in curves_of:
        run_dir = run(algo, options, args, out, cache)
        summary = json.loads((run_dir / "summary.json").read_text())
        seeds = summary["per_seed"]

        def column(key: str, seeds=seeds) -> list[float]:
            return [r.get(key, float("nan")) for r in seeds]

        com = last_values(run_dir, COM_RATE) if algo.startswith("com") else []
        rows.append(
            f"| {label(algo, options)} | {mean_sd(column('final_eval_throughput'))} "
            f"| {mean_sd(column('final_train_throughput'))} "
            f"| {mean_sd(column('final_eval_ratio'))} | {mean_sd(column('final_train_ratio'))} "
            f"| {mean_sd(com, 2) if com else '-'} | {summary['train_seconds']:.0f} |"
        )
        curves[label(algo, options)] = run_dir
    for metric in metrics:
        tail = metric.split("/")[-1]
        compare_plot(curves, metric, out / f"{name}_{tail}.png", f"{name}: {metric}")
    text = "\n".join(rows)
    (out / "table.md").write_text(text + "\n")
    return text


def main() -> None:
    figure_cli(__doc__.split("\n")[0], list(FIGURES), figure)


if __name__ == "__main__":
    main()
