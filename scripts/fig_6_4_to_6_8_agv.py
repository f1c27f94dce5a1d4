"""Figures 6.4-6.8: four-AGV scheduling with Cooperative HRL, its baselines and the rules.

Every curve is one population run (``hrl_torch.experiment.run_experiment``, the CLI's path)
of the ``four-agv`` domain, some with changed env options:

- Figure 6.4: Cooperative HRL, selfish multi-agent HRL, single-agent HRL (Table 6.1 timing);
- Figure 6.5: Cooperative and selfish HRL with 2 s primitive actions (``cooperative-2s``,
  ``selfish-2s``: the ``FIGURE_6_5`` timing, and the learner's init made for it);
- Figure 6.6: flat Q-learning and single-agent HRL, one AGV, buffer capacity 1 (``q``,
  ``single-c1``: the task graph needs the capacity too, not only the env);
- Figure 6.7: Cooperative HRL and the dispatching rules FCFS, HQF, NSF;
- Figure 6.8: cooperation at the root against the root and the navigation level.

Writes per figure ``runs/fig_6_x/`` (run folders with TensorBoard, CSV, PNG, summary) and a
comparison plot of the training throughput (assemblies per 1,000 s, mean over seeds) plus
``table.md`` (final greedy and training throughput, mean ± sd over seeds).

    python scripts/fig_6_4_to_6_8_agv.py [--seeds 5] [--steps 200000] [--only fig_6_4 ...]
"""

from __future__ import annotations

import json
from pathlib import Path

import agents  # noqa: F401  (registers the domains)
from hrl_torch.experiment import RunOptions
from hrl_torch.report import compare_plot, figure_cli, mean_sd, run_variant

TRAIN = "charts/throughput"
FIGURES = {
    "fig_6_4": [("cooperative", {}), ("selfish", {}), ("single", {})],
    "fig_6_5": [("cooperative-2s", {}), ("selfish-2s", {})],
    "fig_6_6": [("q", {}), ("single-c1", {})],
    "fig_6_7": [("cooperative", {}), ("fcfs", {}), ("hqf", {}), ("nsf", {})],
    "fig_6_8": [("cooperative", {}), ("cooperative-nav", {})],
}


def run(algo: str, options: dict, args, out: Path, cache: dict) -> Path:
    """One population run (runs with the same algorithm and options are shared)."""
    opts = RunOptions(seeds=list(range(args.seeds)), steps=args.steps, out=str(out), progress=False)
    return run_variant("four-agv", algo, options, opts, cache)


def label(algo: str, options: dict) -> str:
    """Curve label: the algorithm and its changed env options."""
    extra = [f"capacity {v}" if k == "capacity" else "2 s actions" for k, v in options.items()]
    return " ".join([algo, *extra])


def figure(name: str, args, cache: dict) -> str:
    """Run one figure's curves; plot and tabulate them."""
    out = Path(args.out) / name
    rows = [
        f"### {name}",
        "",
        "| curve | greedy throughput | training throughput (last log) | train s |",
        "|---|---:|---:|---:|",
    ]
    curves = {}
    for algo, options in FIGURES[name]:
        run_dir = run(algo, options, args, out, cache)
        summary = json.loads((run_dir / "summary.json").read_text())
        seeds = summary["per_seed"]
        greedy = [r.get("final_eval_throughput", float("nan")) for r in seeds]
        train = [r.get("final_train_throughput", float("nan")) for r in seeds]
        rows.append(
            f"| {label(algo, options)} | {mean_sd(greedy)} | {mean_sd(train)} "
            f"| {summary['train_seconds']:.0f} |"
        )
        curves[label(algo, options)] = run_dir
    compare_plot(curves, TRAIN, out / f"{name}.png", f"{name}: training throughput")
    text = "\n".join(rows)
    (out / "table.md").write_text(text + "\n")
    return text


def main() -> None:
    figure_cli(__doc__.split("\n")[0], list(FIGURES), figure)


if __name__ == "__main__":
    main()
