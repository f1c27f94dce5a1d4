"""The taxi-fuel sweep table of docs/reproduction.md: one row per trial of sweep folders.

Per trial (a run folder under ``SWEEP/<trial>/``): the final greedy reward per step per seed and
its mean (``summary.json``, ``final_eval_throughput``), the mean final training reward per step
(``final_train_reward_rate``), the training reward per step averaged over the run's logs (mean
over seeds of the mean of ``charts/reward_rate``: the area under the online curve), and the
median first step with a greedy reward per step >= 0.

    python scripts/taxi_fuel_text_sweep_table.py runs/sweeps/hpgrl_alpha runs/sweeps/q_alpha_eps
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
from collections import defaultdict
from pathlib import Path


def trial_row(summary_path: Path) -> str:
    """One table row from a trial's ``summary.json`` and ``progress.csv``."""
    summary = json.loads(summary_path.read_text())
    greedy = [p["final_eval_throughput"] for p in summary["per_seed"]]
    training = [p["final_train_reward_rate"] for p in summary["per_seed"]]
    rates, first = defaultdict(list), {}
    with open(summary_path.parent / "progress.csv") as f:
        for row in csv.DictReader(f):
            if row["metric"] == "charts/reward_rate":
                rates[row["seed"]].append(float(row["value"]))
            elif row["metric"] == "charts/eval_throughput" and float(row["value"]) >= 0:
                first.setdefault(row["seed"], int(row["step"]))
    area = statistics.mean(statistics.mean(v) for v in rates.values())
    n = len(greedy)
    hit = f"never (0/{n})"
    if first:
        hit = f"{statistics.median(first.values()):,.0f} ({len(first)}/{n})"
    cells = [
        summary_path.parent.parent.name,
        ", ".join(f"{x:.3f}" for x in greedy),
        f"{statistics.mean(greedy):.3f}",
        f"{statistics.mean(training):.3f}",
        f"{area:.3f}",
        hit,
    ]
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sweeps", nargs="+", type=Path, help="sweep folders")
    args = parser.parse_args()
    for folder in args.sweeps:
        print(f"## {folder}")
        print(
            "| trial | final greedy (seeds) | mean | final training | training averaged over "
            "the run | first greedy >= 0 (median, seeds) |\n|---|---|---:|---:|---:|---|"
        )
        for path in sorted(folder.glob("*/*/summary.json")):
            print(trial_row(path))


if __name__ == "__main__":
    main()
