"""Initial values, step sizes and all-states updating, measured on every episodic domain.

For each domain, algorithm and setting, one population run of ``--seeds`` seeds (one learner
each) trains for the domain's budget with the domain's exploration; a greedy evaluation every
``budget / 16`` steps records the first one at or above the domain's near-optimal threshold.
A row reports the steps to the threshold per seed (env steps of that learner; ``-`` for a miss),
how many seeds reached it, and how many were at or above it at the end of the budget (a policy
that reached the threshold can fall back below it).

Settings: initial values ``-M`` (pessimistic), ``0`` and ``+M`` (optimistic), ``M`` the
domain's reward scale (``CASES``: the larger of the largest single reward magnitude and the
longest optimal episode's cost, rounded); step sizes 0.1 and 0.5; all-states updating off and
on for the hierarchical learners (the executor records the last 32 states of each child).

Continuing domains (small-agv, agv, agv-ct, four-agv-earlier, trash, two-taxi-earlier) are skipped:
they are evaluated by throughput, not by episodes that reach a goal.

Writes ``--csv`` (one row per run) and the markdown table between the markers of
``--markdown`` (docs/defaults.md).
"""

from __future__ import annotations

import argparse
import csv
import time
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from agents import four_rooms, key_door, taxi, taxi_fuel, toy_text
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.learners import HDRLearner, MaxQLearner, SMDPQLearner
from hrl_torch.runs.domain import DomainSpec
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.config import TrainConfig

LEARNERS = {"maxq-q": MaxQLearner, "hdr": HDRLearner, "q": SMDPQLearner}
HIERARCHICAL = ("maxq-q", "hdr")
VISITED = 32  # states of a child kept for all-states updating
BEGIN, END = "<!-- defaults-table:begin -->", "<!-- defaults-table:end -->"


@dataclass
class Case:
    """One domain as the table measures it.

    Attributes:
        domain: its spec (graphs and exploration come from its ``AlgoSpec``s).
        scale: ``M``; the initial values tried are ``-M``, ``0`` and ``+M``.
        threshold: near-optimal greedy return.
        budgets: env steps per learner, per algorithm.
        gamma: discount of every learner.
        envs_per_learner: ``E``.
        eval_episodes: greedy episodes per evaluation.
        backend: env backend.
        alphas: step sizes tried.
    """

    domain: DomainSpec
    scale: float
    threshold: float
    budgets: dict[str, int]
    gamma: float = 1.0
    envs_per_learner: int = 64
    eval_episodes: int = 100
    backend: str = "torch"
    alphas: tuple[float, ...] = (0.1, 0.5)


GYM = {"envs_per_learner": 16, "eval_episodes": 5, "backend": "gymnasium"}


def cases() -> dict[str, Case]:
    """Every measured domain; budgets keep the whole table near 30 minutes on one core."""
    return {
        "taxi": Case(taxi.DOMAIN, 20.0, 7.5, {"maxq-q": 40_000, "hdr": 40_000, "q": 100_000}),
        # the hierarchy cannot reach the optimum (its root does not see the taxi's location):
        # the threshold is -10, a return both learners reach (docs/reproduction.md, Figure 5.3)
        "taxi-fuel-earlier": Case(
            taxi_fuel.DOMAIN, 20.0, -10.0, {"maxq-q": 400_000, "q": 800_000}, alphas=(0.5,)
        ),
        "four-rooms": Case(
            four_rooms.DOMAIN,
            20.0,
            four_rooms.THRESHOLD,
            {"maxq-q": 100_000, "hdr": 100_000, "q": 100_000},
        ),
        "key-door": Case(
            key_door.DOMAIN,
            25.0,
            key_door.THRESHOLD,
            {"maxq-q": 100_000, "hdr": 100_000, "q": 100_000},
        ),
        # one start, deterministic: 5 greedy episodes differ only in tie-breaking
        "frozenlake-4x4": Case(toy_text.FROZEN_LAKE_4, 1.0, 1.0, {"q": 10_000}, **GYM, gamma=0.99),
        "frozenlake-8x8": Case(toy_text.FROZEN_LAKE_8, 1.0, 1.0, {"q": 40_000}, **GYM, gamma=0.99),
        "cliffwalking": Case(toy_text.CLIFF_WALKING, 100.0, -13.0, {"q": 10_000}, **GYM),
    }


@dataclass
class Setting:
    """One row: an algorithm with an initial value, a step size and all-states on or off."""

    algo: str
    init: float
    alpha: float
    all_states: bool = False

    def learner(self, gamma: float):
        """``(graph, n_learners) -> learner`` for this setting."""
        cls = LEARNERS[self.algo]
        options = {"all_states": self.all_states} if self.algo in HIERARCHICAL else {}
        return lambda g, p: cls(g, p, self.alpha, gamma, init=self.init, **options)


def settings(case: Case) -> list[Setting]:
    """Every setting measured on ``case``.

    Flat Q: every initial value and step size. MAXQ-Q: also all-states updating off and on.
    HDR (about twice MAXQ-Q's cost per step): every initial value at step size 0.5, all-states
    updating off.
    """
    rows = []
    for algo in case.budgets:
        alphas = (0.5,) if algo == "hdr" else case.alphas
        for init in (-case.scale, 0.0, case.scale):
            for alpha in alphas:
                for all_states in (False, True) if algo == "maxq-q" else (False,):
                    rows.append(Setting(algo, init, alpha, all_states))
    return rows


def run(case: Case, setting: Setting, seeds: list[int], budget_scale: float = 1.0) -> dict:
    """One population run of ``setting`` on ``case``; its row of the table."""
    base = case.domain.algos["q" if setting.algo == "q" else "maxq-q"]
    steps = int(case.budgets[setting.algo] * budget_scale)
    spec = replace(
        base,
        learner=setting.learner(case.gamma),
        train=TrainConfig(
            steps=steps,
            eval_every=steps // 16,
            eval_episodes=case.eval_episodes,
            threshold=case.threshold,
            progress=False,
            success_key=base.train.success_key,
        ),
        envs_per_learner=case.envs_per_learner,
        executor=ExecutorConfig(record_visited=VISITED if setting.all_states else 0),
    )
    domain = replace(case.domain, algos={setting.algo: spec})
    opts = RunOptions(seeds=seeds, backend=case.backend, progress=False, tensorboard=False)
    start = time.perf_counter()
    result = build_trainer(domain, setting.algo, opts).train()
    hits = result.steps_to_threshold
    return {
        "domain": case.domain.name,
        "algo": setting.algo,
        "init": setting.init,
        "alpha": setting.alpha,
        "all_states": setting.all_states,
        "budget": steps,
        "threshold": round(case.threshold, 2),
        "reached": sum(h is not None for h in hits),
        "final_ok": sum(v >= case.threshold for v in result.final_eval),
        "seeds": len(seeds),
        "steps_to_threshold": " ".join("-" if h is None else str(h) for h in hits),
        "median_steps": _median(hits),
        "final_eval_mean": round(sum(result.final_eval) / len(seeds), 2),
        "seconds": round(time.perf_counter() - start, 1),
    }


def _median(hits: list[int | None]) -> str:
    """Median steps over all seeds, a miss counting as infinite (``-`` if half or more miss)."""
    ordered = sorted(float("inf") if h is None else h for h in hits)
    mid = ordered[len(ordered) // 2]
    return "-" if mid == float("inf") else f"{int(mid):,}"


def markdown(rows: list[dict]) -> str:
    """The rows as a markdown table."""
    head = (
        "| domain | algo | init | alpha | all-states | budget | reached | at end | median steps "
        "| steps to threshold per seed | final mean | s |\n"
        "|---|---|---:|---:|---|---:|---:|---:|---:|---|---:|---:|\n"
    )
    body = "".join(
        f"| {r['domain']} | {r['algo']} | {float(r['init']):g} | {float(r['alpha']):g} | "
        f"{'on' if str(r['all_states']) == 'True' else 'off'} | {int(r['budget']):,} | "
        f"{r['reached']}/{r['seeds']} | {r['final_ok']}/{r['seeds']} | {r['median_steps']} | "
        f"{r['steps_to_threshold']} | {r['final_eval_mean']} | {r['seconds']} |\n"
        for r in rows
    )
    return head + body


def write_markdown(path: Path, table: str) -> None:
    """Replace the text between the markers of ``path`` by ``table``."""
    text = path.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{path} has no {BEGIN} ... {END} markers")
    before, rest = text.split(BEGIN, 1)
    _, after = rest.split(END, 1)
    path.write_text(f"{before}{BEGIN}\n{table}{END}{after}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--domains", nargs="+", default=None, help="default: every case")
    parser.add_argument("--algos", nargs="+", default=None, help="default: every algorithm")
    parser.add_argument("--budget-scale", type=float, default=1.0, help="scale every budget")
    parser.add_argument("--csv", default="docs/defaults_table.csv")
    parser.add_argument("--markdown", default="docs/defaults.md", help="'' to skip")
    parser.add_argument(
        "--from-csv", action="store_true", help="only rewrite --markdown's table from --csv"
    )
    args = parser.parse_args()
    if args.from_csv:
        with open(args.csv, newline="") as f:
            write_markdown(Path(args.markdown), markdown(list(csv.DictReader(f))))
        return
    torch.set_num_threads(1)
    seeds = list(range(args.seeds))
    rows = []
    start = time.perf_counter()
    with open(args.csv, "w", newline="") as f:  # row by row: a crash keeps what was measured
        writer = None
        for name, case in cases().items():
            if args.domains and name not in args.domains:
                continue
            for setting in settings(case):
                if args.algos and setting.algo not in args.algos:
                    continue
                row = run(case, setting, seeds, args.budget_scale)
                rows.append(row)
                if writer is None:
                    writer = csv.DictWriter(f, fieldnames=list(row))
                    writer.writeheader()
                writer.writerow(row)
                f.flush()
                print(
                    f"{name:15s} {setting.algo:6s} init {setting.init:6g} "
                    f"alpha {setting.alpha:g} all-states {setting.all_states!s:5s}: "
                    f"{row['reached']}/{len(seeds)} reached, {row['final_ok']} at end, "
                    f"steps {row['steps_to_threshold']} ({row['seconds']} s)",
                    flush=True,
                )
    print(f"{len(rows)} runs in {time.perf_counter() - start:.0f} s")
    if args.markdown:
        write_markdown(Path(args.markdown), markdown(rows))


if __name__ == "__main__":
    main()
