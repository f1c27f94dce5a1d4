"""Figures 6.11-6.14: two taxis with Cooperative and COM-Cooperative HRL and their baselines.

Every curve is one population run (``hrl_torch.runs.experiment.run_experiment``, the CLI's path)
of a two-taxi-earlier domain (``--domain``): ``two-taxi`` (default: the text's task, a race's loser
returns empty, one team reward, one arrival process over the grid), ``two-taxi-station``
(the same, an arrival process per station) or ``two-taxi-earlier`` (the first build: a ``Get`` ends
when its passenger is taken, each taxi its own share of the reward).

- Figures 6.11 and 6.12: throughput (passengers delivered per 5,000 steps) and average
  waiting time per passenger of selfish multi-agent HRL, Cooperative HRL, COM-Cooperative HRL
  with ComCost 0 and single-agent HRL (one taxi), passenger arrival rate 10;
- Figure 6.13: waiting time of selfish HRL and COM-Cooperative HRL (ComCost 0) at arrival
  rates 5, 10 and 20 (the text's rate: mean steps between arrivals, ``envs.two_taxi``);
- Figure 6.14: COM-Cooperative HRL with ComCost 0, 1, 5 and 10 against selfish HRL:
  throughput, waiting time and the share of decisions made communicating;
- ``teams``: 6.11 and 6.12 without single-agent HRL;
- ``rules``: the room the task leaves for coordination: hand-written dispatching rules
  (``agents.two_taxi_rules``: racing for the nearest passenger, with the text's Get or the
  first build's, against coordinated choices) at rates 5, 10 and 20 with the domain's
  arrivals, ``--seeds`` seeds x 4 rows x 20,000 steps each;
- ``loss`` (beyond the text): COM-Cooperative HRL with ComCost 0 when 0%, 50% or 100% of the
  replies are lost.

Writes per figure ``OUT/DOMAIN/fig_6_x/`` (run folders with TensorBoard, CSV, PNG, summary),
comparison plots of the training curves (mean over seeds) and ``table.md``: final greedy and
training values and the training curves' means over the whole run (a gap that closes late
shows there), mean ± sd over seeds.

    python scripts/fig_6_11_to_6_14_two_taxi.py [--domain two-taxi] [--seeds 5]
        [--steps 200000] [--eval-every 20000] [--only fig_6_11 ...] [--reuse]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

import agents  # noqa: F401  (registers the domains)
from agents.two_taxi_rules import RULES, measure
from envs.two_taxi import MEAN_INTERARRIVAL
from hrl_torch.runs.experiment import RunOptions
from hrl_torch.runs.report import compare_plot, mean_sd, run_variant
from hrl_torch.training.runlog import read_curves

DOMAINS = ("two-taxi", "two-taxi-station", "two-taxi-earlier")
THROUGHPUT, WAIT, COM_RATE = "charts/throughput", "charts/wait", "charts/communication_rate"
BASE = [("selfish", {}), ("cooperative", {}), ("com-0", {}), ("single", {})]
RATES = (5.0, MEAN_INTERARRIVAL, 20.0)
FIGURES = {
    "fig_6_11": (BASE, [THROUGHPUT]),
    "fig_6_12": (BASE, [WAIT]),
    # 6.11 and 6.12 without the single taxi (for the per-station reading)
    "teams": (BASE[:3], [THROUGHPUT, WAIT]),
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
    """One population run (runs with the same algorithm and options are shared).

    Every run folder records its variant (``variant.json``); with ``--reuse`` a finished run of
    the same variant under ``OUT/DOMAIN`` is read instead of trained again (e.g. made by
    another invocation running other figures at the same time).
    """
    variant = {
        "domain": args.domain,
        "algo": algo,
        "options": options,
        "seeds": list(range(args.seeds)),
        "steps": args.steps,
        "eval_every": args.eval_every,
    }
    if args.reuse:
        for path in sorted(out.glob("**/variant.json")):
            if json.loads(path.read_text()) == variant and (path.parent / "summary.json").exists():
                return path.parent
    opts = RunOptions(
        seeds=variant["seeds"],
        steps=args.steps,
        eval_every=args.eval_every,
        out=str(out),
        progress=False,
    )
    run_dir = run_variant(args.domain, algo, options, opts, cache)
    (run_dir / "variant.json").write_text(json.dumps(variant) + "\n")
    return run_dir


def label(algo: str, options: dict) -> str:
    """Curve label: the algorithm and its arrival rate (mean steps between arrivals)."""
    return f"{algo} rate {options.get('mean_interarrival', MEAN_INTERARRIVAL):g}"


def last_values(run_dir: Path, metric: str) -> list[float]:
    """The last logged value of ``metric`` per seed."""
    _, curves = read_curves(run_dir / "progress.csv", metric)
    return [float(curve[-1]) for curve in curves.values()]


def run_means(run_dir: Path, metric: str) -> list[float]:
    """The mean of ``metric``'s training curve over the whole run, per seed."""
    _, curves = read_curves(run_dir / "progress.csv", metric)
    return [float(np.nanmean(curve)) for curve in curves.values()]


HEADER = [
    "| curve | greedy throughput | training throughput | greedy wait | training wait "
    "| throughput, run mean | wait, run mean | communication rate | train s |",
    "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
]


def figure(name: str, args, cache: dict) -> str:
    """Run one figure's curves; plot and tabulate them."""
    if name == "rules":
        return rules_table(args)
    curves_of, metrics = FIGURES[name]
    out = Path(args.out) / args.domain / name
    rows = [f"### {name} ({args.domain})", "", *HEADER]
    curves = {}
    for algo, options in curves_of:
        run_dir = run(algo, options, args, Path(args.out) / args.domain, cache)
        summary = json.loads((run_dir / "summary.json").read_text())
        seeds = summary["per_seed"]

        def column(key: str, seeds=seeds) -> list[float]:
            return [r.get(key, float("nan")) for r in seeds]

        com = last_values(run_dir, COM_RATE) if algo.startswith("com") else []
        rows.append(
            f"| {label(algo, options)} | {mean_sd(column('final_eval_throughput'))} "
            f"| {mean_sd(column('final_train_throughput'))} "
            f"| {mean_sd(column('final_eval_ratio'))} | {mean_sd(column('final_train_ratio'))} "
            f"| {mean_sd(run_means(run_dir, THROUGHPUT))} | {mean_sd(run_means(run_dir, WAIT))} "
            f"| {mean_sd(com, 2) if com else '-'} | {summary['train_seconds']:.0f} |"
        )
        curves[label(algo, options)] = run_dir
    for metric in metrics:
        tail = metric.split("/")[-1]
        compare_plot(curves, metric, out / f"{name}_{tail}.png", f"{name}: {metric}")
    text = "\n".join(rows)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(text + "\n")
    return text


def rules_table(args) -> str:
    """The hand-written rules at rates 5, 10, 20 with the domain's arrivals."""
    arrivals = "station" if args.domain.endswith("station") else "grid"
    rows = [
        f"### rules (arrivals: {arrivals})",
        "",
        "| rate | rule | throughput | wait | arrivals per 5,000 | wait: race - this rule |",
        "|---:|---|---:|---:|---:|---:|",
    ]
    seeds = tuple(range(args.seeds))
    for rate in RATES:
        results = {r: measure(r, seeds, mean_interarrival=rate, arrivals=arrivals) for r in RULES}
        race = results["race"]["wait"]
        for rule, r in results.items():
            gap = [a - b for a, b in zip(race, r["wait"], strict=True)]
            rows.append(
                f"| {rate:g} | {rule} | {mean_sd(r['throughput'])} | {mean_sd(r['wait'], 2)} "
                f"| {mean_sd(r['arrivals'])} | {mean_sd(gap, 2) if rule != 'race' else '-'} |"
            )
    text = "\n".join(rows)
    out = Path(args.out) / args.domain / "rules"
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(text + "\n")
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--domain", default=DOMAINS[0], choices=DOMAINS)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--out", default="runs")
    parser.add_argument(
        "--eval-every", type=int, default=None, help="greedy evaluations (default: 20,000)"
    )
    parser.add_argument("--reuse", action="store_true", help="read finished runs of a variant")
    names = [*FIGURES, "rules"]
    parser.add_argument("--only", nargs="*", default=names, choices=names)
    args = parser.parse_args()
    if args.seeds < 2:
        parser.error("--seeds must be at least 2 (the tables give a spread over seeds)")
    torch.set_num_threads(1)
    cache: dict = {}
    for name in args.only:
        print(figure(name, args, cache), flush=True)


if __name__ == "__main__":
    main()
