"""Taxi-fuel, Figure 5.3: HPGRL against MAXQ-Q and flat Q-learning, 10 seeds each.

The text's claims (Section 5.2.1): MAXQ-Q converges fastest, HPGRL reaches MAXQ-Q's performance
but much more slowly, flat Q-learning is the slowest (HPGRL slightly faster). Each algorithm
trains all seeds as one population (``hrl-torch train taxi-fuel-earlier --algo ...``); the greedy
return over 100 fixed evaluation episodes is the curve. The threshold is the optimal policy's
expected return (computed here by value iteration over the 6,500 states) minus 2.

Writes a run folder per algorithm, ``<out>/taxi_fuel_compare/eval_return.png`` (Figure 5.3) and
``table.md`` (the rows of docs/reproduction.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from agents.taxi_fuel import DOMAIN
from envs.taxi_fuel import TaxiFuelEnv, transition_tables
from hrl_torch.runs.experiment import RunOptions, format_summary, run_experiment
from hrl_torch.runs.report import TABLE_HEADER, compare_plot, summary_row

BUDGETS = {"maxq-q": 1_000_000, "hpgrl": 3_000_000, "q": 3_000_000}
LABELS = {"maxq-q": "MAXQ-Q", "hpgrl": "HPGRL", "q": "flat Q-learning"}


def optimal_return() -> tuple[float, float]:
    """Expected optimal return over the start distribution, and over the evaluation episodes."""
    nxt, reward, terminal, starts = transition_tables()
    v = torch.zeros(nxt.shape[0], dtype=torch.float64)
    for _ in range(500):
        v = (reward.double() + torch.where(terminal, 0.0, v[nxt])).max(1).values
    eval_obs = TaxiFuelEnv([DOMAIN.eval_seed], 100).reset()["observation"]
    return v[starts].mean().item(), v[eval_obs].mean().item()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--out", default="runs")
    parser.add_argument("--algos", nargs="+", default=["maxq-q", "hpgrl", "q"])
    parser.add_argument("--steps", type=int, default=None, help="override every budget")
    args = parser.parse_args()
    expected, on_eval = optimal_return()
    threshold = round(on_eval - 2.0, 2)
    print(f"optimal expected return {expected:.2f}; on the 100 evaluation episodes {on_eval:.2f}")
    runs, rows = {}, []
    for algo in args.algos:
        opts = RunOptions(
            seeds=list(range(args.seeds)),
            out=args.out,
            steps=args.steps or BUDGETS[algo],
            threshold=threshold,
            progress=True,
        )
        run_dir, summary = run_experiment(DOMAIN, algo, opts)
        print(format_summary(summary))
        runs[LABELS[algo]] = run_dir
        rows.append(summary_row(LABELS[algo], summary))
    out = Path(args.out) / "taxi_fuel_compare"
    plot = compare_plot(
        runs,
        "charts/eval_return",
        out / "eval_return.png",
        "Taxi-fuel (Figure 5.3): greedy evaluation return",
        {
            f"optimal on the eval episodes ({on_eval:.2f})": on_eval,
            f"threshold {threshold}": threshold,
        },
        ylim=(-60, 10),
    )
    training = compare_plot(
        runs,
        "charts/episode_return",
        out / "training_return.png",
        "Taxi-fuel: return of training episodes (with exploration)",
        {f"optimal ({expected:.2f})": expected},
        ylim=(-120, 10),
    )
    print(f"plot: {training}")
    table = "\n".join([TABLE_HEADER, *rows])
    (out / "table.md").write_text(table + "\n")
    print(table)
    print(f"plot: {plot}")


if __name__ == "__main__":
    main()
