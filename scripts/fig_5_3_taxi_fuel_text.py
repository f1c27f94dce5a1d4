"""Taxi-fuel as the text sets it (Figure 5.3): average reward per step of MAXQ-Q, HPGRL, flat Q.

Domain ``taxi-fuel`` (``agents.taxi_fuel_text``): the text's 8,750 states, no time limit,
the root over the full state, and the text's measure, the average reward per step over the run.
Each algorithm trains all seeds as one population (``hrl-torch train taxi-fuel --algo
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

from agents.taxi_fuel_text import DOMAIN, EVAL_HORIZON, EVAL_ROWS
from envs.taxi_fuel_text import TaxiFuelTextEnv, transition_tables
from hrl_torch.runs.experiment import RunOptions, format_summary, run_experiment
from hrl_torch.runs.report import compare_plot, median_or_none
from hrl_torch.training.runlog import read_curves

LABELS = {
    "maxq-q": "MAXQ-Q",
    "hpgrl": "HPGRL",
    "q": "flat Q-learning",
    "maxq-q-fuel": "MAXQ-Q, fuel in every node",
}
GREEDY, TRAINING = "charts/eval_throughput", "charts/reward_rate"
#: greedy reward per step levels of the table (the optimal policy shows 0.265 as evaluated)
LEVELS = (0.0, 0.15, 0.25)


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


def optimal_measured(sweeps: int = 300) -> float:
    """The return-optimal policy's reward per step under the greedy evaluation's protocol.

    ``EVAL_ROWS`` rows of the evaluation seed, ``EVAL_HORIZON`` steps from a reset: the run
    ends mid-episode, before that episode's +20, so this is below the gain (what a learned
    policy as good as the optimum shows on the greedy curve).
    """
    nxt, reward, terminal, _ = transition_tables()
    v = torch.zeros(nxt.shape[0], dtype=torch.float64)
    for _ in range(sweeps):
        q = reward.double() + torch.where(terminal, 0.0, v[nxt])
        v = q.max(1).values
    policy = q.argmax(1)
    env = TaxiFuelTextEnv([DOMAIN.eval_seed], EVAL_ROWS)
    td, total = env.reset(), 0.0
    for _ in range(EVAL_HORIZON):
        td = env.step(policy[td["observation"]])
        total += float(td["reward"].sum())
    return total / (EVAL_ROWS * EVAL_HORIZON)


def first_at(steps: np.ndarray, curve: np.ndarray, level: float) -> int | None:
    """The first step at which ``curve`` is >= ``level`` (``None``: never)."""
    hit = np.nonzero(curve >= level)[0]
    return int(steps[hit[0]]) if len(hit) else None


def hit_cell(steps: np.ndarray, curves: dict, level: float) -> str:
    """Median first step at ``level`` over the seeds that reach it, and how many do."""
    hits = [first_at(steps, c, level) for c in curves.values()]
    med = median_or_none(hits)
    n = sum(h is not None for h in hits)
    return ("never" if med is None else f"{med:,.0f}") + f" ({n}/{len(hits)})"


def table_row(label: str, run_dir: Path, budget: int) -> str:
    """Steps to each greedy level and to a training rate >= 0; final and best rates."""
    steps, greedy = read_curves(run_dir / "progress.csv", GREEDY)
    t_steps, training = read_curves(run_dir / "progress.csv", TRAINING)
    cells = [label, f"{budget:,}", *(hit_cell(steps, greedy, level) for level in LEVELS)]
    cells.append(hit_cell(t_steps, training, 0.0))
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
    + " | training >= 0 (median, seeds) | final greedy reward/step | best mean greedy"
    + " | final training reward/step |\n"
    + "|---|---:|"
    + "---|" * (len(LEVELS) + 1)
    + "---:|---:|---:|"
)


def _options(args, budget: int) -> RunOptions:
    return RunOptions(
        seeds=list(range(args.seeds)),
        out=args.out,
        steps=budget,
        envs_per_learner=args.envs_per_seed,
        eval_every=args.eval_every,
        progress=False,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--out", default="runs")
    parser.add_argument("--algos", nargs="+", default=["maxq-q", "hpgrl", "q"])
    parser.add_argument("--steps", type=int, default=None, help="override every budget")
    parser.add_argument("--envs-per-seed", type=int, default=None)
    parser.add_argument("--eval-every", type=int, default=None)
    parser.add_argument(
        "--reuse", nargs="*", default=[], metavar="ALGO=RUN_DIR",
        help="take these algorithms' finished run folders instead of training them",
    )  # fmt: skip
    parser.add_argument("--train-only", action="store_true", help="no reference, no table")
    args = parser.parse_args()
    reuse = dict(item.split("=", 1) for item in args.reuse)
    torch.set_num_threads(1)  # (before the value iteration: the CPU is shared)
    runs, rows = {}, []
    for algo in args.algos:
        budget = args.steps or DOMAIN.algos[algo].train.steps
        if algo in reuse:
            run_dir = Path(reuse[algo])  # (a run cut short: up to its last evaluation)
            budget = int(read_curves(run_dir / "progress.csv", GREEDY)[0][-1])
        else:
            run_dir, summary = run_experiment(DOMAIN, algo, _options(args, budget))
            print(format_summary(summary), flush=True)
        runs[LABELS[algo]] = Path(run_dir)
        rows.append(table_row(LABELS[algo], Path(run_dir), budget))
    if args.train_only:
        return
    gain, measured = optimal_gain(), optimal_measured()
    print(f"optimal average reward per step {gain:.4f} ({measured:.4f} as evaluated)")
    out = Path(args.out) / "taxi_fuel_text_compare"
    reference = {
        f"optimal gain ({gain:.3f})": gain,
        f"optimal policy, as evaluated ({measured:.3f})": measured,
    }
    for metric, name, what in (
        (GREEDY, "eval_reward_rate.png", "greedy policy"),
        (TRAINING, "training_reward_rate.png", "training, with exploration"),
    ):
        title = f"Taxi-fuel as the text sets it: average reward per step ({what})"
        print(f"plot: {compare_plot(runs, metric, out / name, title, reference, ylim=(-3, 0.5))}")
    table = "\n".join([HEADER, *rows])
    head = f"optimal gain {gain:.4f}; the optimal policy as evaluated {measured:.4f}"
    (out / "table.md").write_text(f"{head}\n\n{table}\n")
    print(table)


if __name__ == "__main__":
    main()
