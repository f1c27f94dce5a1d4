"""Taxi-fuel as the text sets it (Figure 5.3): average reward per step of MAXQ-Q, HPGRL, flat Q.

Domain ``taxi-fuel-text`` (``agents.taxi_fuel_text``): the text's 8,750 states, no time limit,
the root over the full state, and the text's measure, the average reward per step over the run.
Each algorithm trains all seeds as one population (``hrl-torch train taxi-fuel-text --algo
...``). Two curves per algorithm: the greedy policy's reward per step (``charts/eval_throughput``,
32 rows x 500 steps, episodes one after the other) and the training reward per step with
exploration (``charts/reward_rate``). The reference is the optimal gain, by value iteration
over the 8,750 states (the largest ``rho`` at which the best expected ``sum (r - rho)`` of an
episode is still >= 0).

Writes a run folder per algorithm and ``<out>/taxi_fuel_text_compare/`` with both plots and
``table.md`` (the rows of docs/reproduction.md).
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import numpy as np
import torch

from agents.taxi_fuel_text import DOMAIN
from envs.taxi_fuel_text import transition_tables
from hrl_torch.experiment import RunOptions, format_summary, run_experiment
from hrl_torch.report import compare_plot, median_or_none
from hrl_torch.runlog import read_curves

LABELS = {"maxq-q": "MAXQ-Q", "hpgrl": "HPGRL", "q": "flat Q-learning"}
GREEDY, TRAINING = "charts/eval_throughput", "charts/reward_rate"
#: greedy reward per step levels of the table (the optimal gain is about 0.318)
LEVELS = (0.0, 0.2, 0.3)


def best_episode_value(rho: float, sweeps: int = 300) -> float:
    """``max E[sum (r - rho)]`` of an episode from the start distribution (value iteration)."""
    nxt, reward, terminal, starts = transition_tables()
    v = torch.zeros(nxt.shape[0], dtype=torch.float64)
    for _ in range(sweeps):
        v = (reward.double() - rho + torch.where(terminal, 0.0, v[nxt])).max(1).values
    return v[starts].mean().item()


def optimal_gain(tol: float = 1e-6) -> float:
    """The largest average reward per step over episodes one after the other (bisection)."""
    lo, hi = -1.0, 20.0  # a loop of Fillups earns -1; no step earns more than 20
    while hi - lo > tol:
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if best_episode_value(mid) >= 0 else (lo, mid)
    return lo


def first_at(steps: np.ndarray, curve: np.ndarray, level: float) -> int | None:
    """The first step at which ``curve`` is >= ``level`` (``None``: never)."""
    hit = np.nonzero(curve >= level)[0]
    return int(steps[hit[0]]) if len(hit) else None


def table_row(label: str, run_dir: Path, budget: int) -> str:
    """Steps to each greedy level (median, seeds), final greedy and training reward per step."""
    steps, greedy = read_curves(run_dir / "progress.csv", GREEDY)
    t_steps, training = read_curves(run_dir / "progress.csv", TRAINING)
    cells = [label, f"{budget:,}"]
    for level in LEVELS:
        hits = [first_at(steps, c, level) for c in greedy.values()]
        med = median_or_none(hits)
        n = sum(h is not None for h in hits)
        cells.append(("never" if med is None else f"{med:,.0f}") + f" ({n}/{len(hits)})")
    finals = [c[-1] for c in greedy.values()]
    best = np.nanmax(np.nanmean(np.stack(list(greedy.values())), 0))
    train_final = [c[-1] for c in training.values()]
    sd = statistics.stdev(finals) if len(finals) > 1 else 0.0
    cells += [f"{statistics.mean(finals):.3f} ± {sd:.3f}", f"{best:.3f}"]
    cells.append(f"{statistics.mean(train_final):.3f}")
    return "| " + " | ".join(cells) + " |"


HEADER = (
    "| algorithm | budget (env steps per seed) | "
    + " | ".join(f"greedy >= {v} (median, seeds)" for v in LEVELS)
    + " | final greedy reward/step | best mean greedy | final training reward/step |\n"
    + "|---|---:|"
    + "---|" * len(LEVELS)
    + "---:|---:|---:|"
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--out", default="runs")
    parser.add_argument("--algos", nargs="+", default=["maxq-q", "hpgrl", "q"])
    parser.add_argument("--steps", type=int, default=None, help="override every budget")
    parser.add_argument("--envs-per-seed", type=int, default=None)
    args = parser.parse_args()
    gain = optimal_gain()
    print(f"optimal average reward per step {gain:.4f}")
    runs, rows = {}, []
    for algo in args.algos:
        budget = args.steps or DOMAIN.algos[algo].train.steps
        opts = RunOptions(
            seeds=list(range(args.seeds)),
            out=args.out,
            steps=budget,
            envs_per_learner=args.envs_per_seed,
            progress=False,
        )
        run_dir, summary = run_experiment(DOMAIN, algo, opts)
        print(format_summary(summary), flush=True)
        runs[LABELS[algo]] = Path(run_dir)
        rows.append(table_row(LABELS[algo], Path(run_dir), budget))
    out = Path(args.out) / "taxi_fuel_text_compare"
    reference = {f"optimal gain ({gain:.3f})": gain}
    for metric, name, what in (
        (GREEDY, "eval_reward_rate.png", "greedy policy"),
        (TRAINING, "training_reward_rate.png", "training, with exploration"),
    ):
        title = f"Taxi-fuel as the text sets it: average reward per step ({what})"
        print(f"plot: {compare_plot(runs, metric, out / name, title, reference, ylim=(-3, 0.5))}")
    table = "\n".join([HEADER, *rows])
    (out / "table.md").write_text(f"optimal gain {gain:.4f}\n\n{table}\n")
    print(table)


if __name__ == "__main__":
    main()
