"""Figures 6.4-6.8: four-AGV scheduling with Cooperative HRL, its baselines and the rules.

Every curve is one population run (``hrl_torch.runs.experiment.run_experiment``, the CLI's path).
Two readings of the task (``--variant``):

``text`` (default, domain ``four-agv``, ``agents/four_agv_text.py``): committed jobs that
wait at an empty bay / a full buffer, a root over buffer levels, one team reward, per-AGV
dispatching rules without reservations:

- Figure 6.4: Cooperative HRL, selfish multi-agent HRL, single-agent HRL (Table 6.1 timing);
- Figure 6.5: the same three with 2 s primitive actions (``*-2s``);
- Figure 6.7: Cooperative HRL and the per-AGV rules FCFS, HQF, NSF (``fig_6_7``), and the same
  with 2 s moves (``fig_6_7_2s``).

A figure's runs are shared with the figures after it in one process (``--only fig_6_5
fig_6_7_2s`` trains ``cooperative-2s`` once).

``old`` (domain ``four-agv-earlier``, ``agents/four_agv.py``): jobs that end when their item is
gone, the "job available" root, own rewards, centralised rules with reservations:

- Figure 6.4: Cooperative HRL, selfish multi-agent HRL, single-agent HRL (Table 6.1 timing);
- Figure 6.5: Cooperative and selfish HRL with 2 s primitive actions (``cooperative-2s``,
  ``selfish-2s``: the ``FIGURE_6_5`` timing, and the learner's init made for it);
- Figure 6.6: flat Q-learning and single-agent HRL, one AGV, buffer capacity 1 (``q``,
  ``single-c1``: the task graph needs the capacity too, not only the env);
- Figure 6.7: Cooperative HRL and the dispatching rules FCFS, HQF, NSF;
- Figure 6.8: cooperation at the root against the root and the navigation level.

Writes per figure ``OUT/fig_6_x/`` (run folders with TensorBoard, CSV, PNG, summary) and a
comparison plot of the training throughput (assemblies per 1,000 s, mean over seeds) plus
``table.md``: final greedy and training throughput, mean ± sd over seeds, the greedy values
per seed, and (text variant) Cooperative HRL's greedy gap to each other curve against twice
the standard error of the difference of the two means.

    python scripts/fig_6_4_to_6_8_agv.py [--variant text|old] [--seeds 5] [--steps 200000]
        [--only fig_6_4 ...] [--out runs]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

import agents  # noqa: F401  (registers the domains)
from hrl_torch.runs.experiment import RunOptions
from hrl_torch.runs.report import compare_plot, figure_cli, mean_sd, run_variant

TRAIN = "charts/throughput"
FIGURES_OLD = {
    "fig_6_4": [("cooperative", {}), ("selfish", {}), ("single", {})],
    "fig_6_5": [("cooperative-2s", {}), ("selfish-2s", {})],
    "fig_6_6": [("q", {}), ("single-c1", {})],
    "fig_6_7": [("cooperative", {}), ("fcfs", {}), ("hqf", {}), ("nsf", {})],
    "fig_6_8": [("cooperative", {}), ("cooperative-nav", {})],
}
FIGURES_TEXT = {
    "fig_6_4": [("cooperative", {}), ("selfish", {}), ("single", {})],
    "fig_6_5": [("cooperative-2s", {}), ("selfish-2s", {}), ("single-2s", {})],
    "fig_6_7": [("cooperative", {}), ("fcfs", {}), ("hqf", {}), ("nsf", {})],
    "fig_6_7_2s": [("cooperative-2s", {}), ("fcfs-2s", {}), ("hqf-2s", {}), ("nsf-2s", {})],
}
VARIANTS = {"text": ("four-agv", FIGURES_TEXT), "old": ("four-agv-earlier", FIGURES_OLD)}


def _variant() -> str:
    """Read (and remove) ``--variant`` from the command line; the rest is ``figure_cli``'s."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--variant", choices=list(VARIANTS), default="text")
    known, rest = parser.parse_known_args()
    sys.argv = [sys.argv[0], *rest]
    return known.variant


VARIANT = _variant() if __name__ == "__main__" else "text"
DOMAIN, FIGURES = VARIANTS[VARIANT]


def run(algo: str, options: dict, args, out: Path, cache: dict) -> Path:
    """One population run (runs with the same algorithm and options are shared)."""
    opts = RunOptions(seeds=list(range(args.seeds)), steps=args.steps, out=str(out), progress=False)
    return run_variant(DOMAIN, algo, options, opts, cache)


def label(algo: str, options: dict) -> str:
    """Curve label: the algorithm and its changed env options."""
    extra = [f"capacity {v}" if k == "capacity" else "2 s actions" for k, v in options.items()]
    return " ".join([algo, *extra])


def gap(coop: list[float], other: list[float]) -> str:
    """Cooperative's mean minus ``other``'s, and twice the standard error of that difference."""
    if len(coop) < 2 or len(other) < 2:
        return "n/a"
    diff = statistics.mean(coop) - statistics.mean(other)
    se = math.sqrt(statistics.variance(coop) / len(coop) + statistics.variance(other) / len(other))
    verdict = "yes" if diff > 2 * se else "no"
    return f"{diff:+.1f} (2 SE {2 * se:.1f}: {verdict})"


def figure(name: str, args, cache: dict) -> str:
    """Run one figure's curves; plot and tabulate them."""
    out = Path(args.out) / name
    rows = [
        f"### {name} ({DOMAIN})",
        "",
        "| curve | greedy throughput | training throughput (last log) | greedy per seed "
        "| Cooperative's greedy gap | train s |",
        "|---|---:|---:|---|---|---:|",
    ]
    curves, greedy_of = {}, {}
    for algo, options in FIGURES[name]:
        run_dir = run(algo, options, args, out, cache)
        summary = json.loads((run_dir / "summary.json").read_text())
        seeds = summary["per_seed"]
        greedy = [r.get("final_eval_throughput", float("nan")) for r in seeds]
        train = [r.get("final_train_throughput", float("nan")) for r in seeds]
        greedy_of[algo] = greedy
        coop = "cooperative-2s" if algo.endswith("-2s") else "cooperative"
        vs = (
            ""
            if algo.startswith("cooperative") or coop not in greedy_of
            else gap(greedy_of[coop], greedy)
        )
        per_seed = ", ".join(f"{v:.1f}" for v in greedy)
        rows.append(
            f"| {label(algo, options)} | {mean_sd(greedy)} | {mean_sd(train)} | {per_seed} "
            f"| {vs} | {summary['train_seconds']:.0f} |"
        )
        curves[label(algo, options)] = run_dir
    compare_plot(curves, TRAIN, out / f"{name}.png", f"{name}: training throughput")
    text = "\n".join(rows)
    (out / "table.md").write_text(text + "\n")
    return text


def main() -> None:
    figure_cli(f"{__doc__.split(chr(10))[0]} ({DOMAIN})", list(FIGURES), figure)


if __name__ == "__main__":
    main()
