"""Taxi MAXQ-Q speed: the batched population trainer against a plain-Python MAXQ-Q, in one run.

Three measurements, all on this machine in this process:

(a) wall-clock until all 10 seeds' greedy policies reach the threshold (mean return >= 7.5 over
    the 100 common evaluation episodes), batched: the 10 seeds as one population built by
    ``build_trainer(DOMAIN, "maxq-q", ...)``, for a few ``envs_per_learner`` x evaluation
    intervals;
(b) the same for ``benchmarks/plain_maxq.py`` running the 10 seeds one after another, with the
    same hyperparameters (read from the learner the batched trainer builds), the same 100
    evaluation episodes and the same evaluation intervals;
(c) training env-steps/s of the batched path (one learner x one env, and populations x envs)
    against the plain reference.

Timing rule: both sides are timed from their first training step until the evaluation that
finds the (last) seed at the threshold, *including* the evaluations (of the seeds not yet at
the threshold: the plain side stops a seed once it is there); the training part alone is
reported too (same rule on both sides: evaluations excluded). Set-up (building tables, the
trainer, gymnasium's transition table) is excluded on both sides; the batched side is warmed
up once before timing (first-call overheads of torch). CPU seconds of the process are reported
next to wall seconds because these machines are shared.

Run ``python scripts/bench.py`` (``--quick`` for a smoke run, ``--help`` for options).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field

import gymnasium
import torch

from agents.taxi import DOMAIN
from benchmarks import plain_maxq
from benchmarks.plain_maxq import GymTaxi, Hyper, PlainRun, TableTaxi
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.modules.schedules import Constant, Linear
from hrl_torch.runs.experiment import RunOptions, build_trainer

ALGO = "maxq-q"
COMPILE_STEP = False  # ``--compile-step``: the batched trainers compile their step (the CPU)


# ---------------------------------------------------------------------- machine
def machine() -> dict:
    """What the numbers were measured on."""
    model = "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        git = ["git", "-C", os.path.dirname(os.path.abspath(__file__))]
        commit = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True)
        dirty = subprocess.run(
            [*git, "status", "--porcelain", "--untracked-files=no"], capture_output=True
        )
        code = commit.stdout.decode().strip() + (" + uncommitted changes" if dirty.stdout else "")
    except OSError:
        code = "unknown"
    return {
        "date": time.strftime("%Y-%m-%d %H:%M %Z"),
        "code": code or "unknown",
        "nproc": len(os.sched_getaffinity(0)),
        "cpu": model,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "gymnasium": gymnasium.__version__,
    }


def load() -> str:
    """The 1/5/15-minute load averages."""
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


# ---------------------------------------------------------------------- set-up
def make_trainer(seeds: list[int], envs: int, eval_episodes: int | None = None):
    """The ``maxq-q`` trainer of ``agents/taxi.py`` for ``seeds`` as one population."""
    opts = RunOptions(
        seeds=seeds,
        envs_per_learner=envs,
        eval_episodes=eval_episodes,
        progress=False,
        tensorboard=False,
        compile_step=COMPILE_STEP,
    )
    return build_trainer(DOMAIN, ALGO, opts)


def hyper_of(trainer) -> Hyper:
    """The plain reference's hyperparameters, copied from the batched trainer's learner."""
    learner, exploration = trainer.learner, trainer.policy.exploration
    if not isinstance(learner.alpha, Constant):
        raise TypeError(f"the plain reference needs a constant alpha, got {learner.alpha}")
    if not (isinstance(exploration, EpsilonGreedy) and isinstance(exploration.epsilon, Linear)):
        raise TypeError(f"the plain reference needs a linear epsilon-greedy, got {exploration}")
    for flag in ("internal", "all_states"):
        if getattr(learner, flag, False):
            raise ValueError(f"the plain reference does not implement {flag}=True")
    if learner.layout.per_instance:
        raise ValueError("the plain reference keeps one table per subtask (recursive optimality)")
    c_init, v_init = learner.C.data.unique(), learner.V.data.unique()
    if c_init.numel() != 1 or v_init.numel() != 1:
        raise ValueError("the plain reference needs uniform initial tables")
    eps = exploration.epsilon
    return Hyper(
        alpha=learner.alpha.value,
        gamma=learner.gamma,
        eps_start=eps.start,
        eps_end=eps.end,
        eps_steps=eps.steps,
        c_init=float(c_init),
        v_init=float(v_init),
    )


def eval_starts(n_episodes: int) -> list[int]:
    """Start states of the trainer's evaluation episodes (the eval env's first reset)."""
    env = DOMAIN.make_env([DOMAIN.eval_seed], n_episodes, "torch")
    if env.max_episode_steps != plain_maxq.MAX_EPISODE_STEPS:
        raise ValueError("the batched and plain time limits differ")
    return env.reset()["observation"].tolist()


def warm_up(seeds: list[int]) -> None:
    """First calls of every torch op on the batched path, outside the timings."""
    trainer = make_trainer(seeds, 8)
    for _ in range(3):
        trainer.train_step()
    trainer.evaluate()


# ---------------------------------------------------------------------- (a) batched
@dataclass
class BatchedRun:
    """The population's run to the threshold."""

    envs: int
    eval_every: int
    wall: float
    cpu: float
    train: float
    eval: float
    evaluations: int
    steps_per_learner: int
    steps_to_threshold: list[int | None]


def batched_to_threshold(
    seeds: list[int], envs: int, eval_every: int, max_steps: int
) -> BatchedRun:
    """Train the population, evaluating every ``eval_every`` env steps per learner, until every
    learner has reached the threshold once (or ``max_steps`` per learner ran out)."""
    trainer = make_trainer(seeds, envs)
    threshold = trainer.config.threshold
    hits: list[int | None] = [None] * len(seeds)
    train = evaluate = 0.0
    n_evals, next_eval = 0, eval_every
    wall0, cpu0 = time.perf_counter(), time.process_time()
    while None in hits and trainer.step < max_steps:
        t0 = time.perf_counter()
        trainer.train_step()
        t1 = time.perf_counter()
        train += t1 - t0
        if trainer.step >= next_eval:
            # (the seeds still below the threshold only, as the plain side stops a seed that
            # reached it; theirs are the numbers of a full evaluation)
            mean, _ = trainer.evaluate(learners=[p for p, hit in enumerate(hits) if hit is None])
            evaluate += time.perf_counter() - t1
            n_evals += 1
            next_eval = trainer.step + eval_every
            for p, value in enumerate(mean.tolist()):
                if hits[p] is None and value >= threshold:
                    hits[p] = trainer.step
    return BatchedRun(
        envs,
        eval_every,
        time.perf_counter() - wall0,
        time.process_time() - cpu0,
        train,
        evaluate,
        n_evals,
        trainer.step,
        hits,
    )


# ---------------------------------------------------------------------- (b) plain
@dataclass
class PlainSeries:
    """The plain reference's seeds, one after another."""

    eval_every: int
    wall: float
    cpu: float
    runs: list[PlainRun] = field(default_factory=list)

    @property
    def train(self) -> float:
        return sum(r.train_seconds for r in self.runs)

    @property
    def eval(self) -> float:
        return sum(r.eval_seconds for r in self.runs)


def plain_to_threshold(
    seeds: list[int],
    hyper: Hyper,
    starts: list[int],
    eval_every: int,
    threshold: float,
    max_steps: int,
) -> PlainSeries:
    """Every seed of the plain reference to the threshold, one after another."""
    runs = [
        plain_maxq.train_to_threshold(s, hyper, starts, eval_every, threshold, max_steps)
        for s in seeds
    ]
    # each PlainRun times its seed from the first step: set-up is excluded as on the batched side
    return PlainSeries(
        eval_every, sum(r.seconds for r in runs), sum(r.cpu_seconds for r in runs), runs
    )


# ---------------------------------------------------------------------- cross-check
def cross_check(series: PlainSeries, starts: list[int]) -> float:
    """Largest gap between the plain learners' own evaluation and ``Trainer.evaluate`` of the
    same tables copied into a batched learner (checks abstractions, layout and protocol)."""
    agents = [r.agent for r in series.runs]
    trainer = make_trainer(list(range(len(agents))), 1, eval_episodes=len(starts))
    graph, learner = trainer.graph, trainer.learner
    with torch.no_grad():
        for p, agent in enumerate(agents):
            for node, rows in agent.C.items():
                learner.C.view(graph.index[plain_maxq.NAMES[node]], p).copy_(torch.tensor(rows))
            for node, values in agent.V.items():
                table = learner.V.view(graph.index[plain_maxq.NAMES[node]], p)
                table.copy_(torch.tensor(values)[:, None])
    batched = trainer.evaluate()[0].tolist()
    plain = [agent.evaluate(starts) for agent in agents]
    return max(abs(a - b) for a, b in zip(batched, plain, strict=True))


# ---------------------------------------------------------------------- (c) throughput
def batched_steps_per_second(n_learners: int, envs: int, seconds: float) -> tuple[float, float]:
    """Training env steps/s (all learners) and ms per batched step, from a fresh population."""
    trainer = make_trainer(list(range(n_learners)), envs, eval_episodes=0)
    for _ in range(5 if COMPILE_STEP else 3):  # (compiled: the capture at step 4 too)
        trainer.train_step()
    n, start = 0, time.perf_counter()
    while n < 3 or time.perf_counter() - start < seconds:
        trainer.train_step()
        n += 1
    dt = time.perf_counter() - start
    return n * n_learners * envs / dt, 1e3 * dt / n


# ---------------------------------------------------------------------- report
def fmt_steps(values: list[int | None]) -> str:
    """Mean (min-max) of the steps to threshold; ``n missed`` if some never got there."""
    got = [v for v in values if v is not None]
    missed = len(values) - len(got)
    if not got:
        return "none reached"
    text = f"{statistics.mean(got):,.0f} ({min(got):,}-{max(got):,})"
    return text + (f", {missed} missed" if missed else "")


def ratio(x: float) -> str:
    """``2.35x``, or three significant digits below 0.1."""
    return f"{x:.2f}x" if x >= 0.1 else f"{x:.3g}x"


def report(results: dict) -> str:
    """The markdown the benchmark prints."""
    m, h = results["machine"], results["hyper"]
    lines = [
        f"# Taxi MAXQ-Q benchmark ({m['date']})",
        "",
        f"Machine: {m['nproc']} CPUs ({m['cpu']}), Python {m['python']}, torch {m['torch']} "
        f"with {m['torch_threads']} thread(s), gymnasium {m['gymnasium']}.",
        f"Code: {m['code']}. Command: `{results['command']}`",
        f"Hyperparameters (read from the `{ALGO}` learner of agents/taxi.py, used by both): "
        f"alpha {h['alpha']}, gamma {h['gamma']}, epsilon {h['eps_start']} -> {h['eps_end']} "
        f"over {h['eps_steps']:,} env steps, initial C {h['c_init']}, initial V {h['v_init']}.",
        f"Load average (1/5/15 min): {results['load']['start']} at the start, "
        f"{results['load']['after_threshold']} after (a)+(b), {results['load']['end']} at the end.",
        "",
        f"## Time to threshold: {results['n_seeds']} seeds, greedy mean return >= "
        f"{results['threshold']} over {results['eval_episodes']} evaluation episodes",
        "",
        "| implementation | envs/learner | eval every | wall s (incl. eval) | train s | eval s "
        "| evals | CPU s | env steps to threshold, mean (min-max) | env steps in all |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for r in results["batched"]:
        lines.append(
            f"| batched population | {r['envs']} | {r['eval_every']:,} | {r['wall']:.2f} | "
            f"{r['train']:.2f} | {r['eval']:.2f} | {r['evaluations']} | {r['cpu']:.2f} | "
            f"{fmt_steps(r['steps_to_threshold'])} | "
            f"{r['steps_per_learner'] * results['n_seeds']:,} |"
        )
    for r in results["plain"]:
        steps = [x["steps_to_threshold"] for x in r["runs"]]
        total = sum(x["steps"] for x in r["runs"])
        lines.append(
            f"| plain Python, seeds in turn | 1 | {r['eval_every']:,} | {r['wall']:.2f} | "
            f"{r['train']:.2f} | {r['eval']:.2f} | {sum(x['evaluations'] for x in r['runs'])} | "
            f"{r['cpu']:.2f} | {fmt_steps(steps)} | {total:,} |"
        )
    s = results["summary"]
    lines += [
        "",
        f"- Best batched (E={s['batched_envs']}, eval every {s['batched_eval_every']:,}) "
        f"{s['batched_wall']:.2f} s vs best plain (eval every {s['plain_eval_every']:,}) "
        f"{s['plain_wall']:.2f} s including evaluation: **{s['speedup_wall']:.2f}x** "
        f"(goal: 10x).",
        f"- Training only (evaluation excluded on both sides, same runs): batched "
        f"{s['batched_train']:.2f} s vs plain {s['plain_train']:.2f} s: "
        f"**{s['speedup_train']:.2f}x**.",
        f"- Every batched seed reached the threshold: {s['batched_all_reached']}; every plain "
        f"seed: {s['plain_all_reached']}.",
        f"- Cross-check: the plain tables copied into the batched learner and evaluated by "
        f"`Trainer.evaluate` differ from the plain evaluation by at most "
        f"{results['cross_check']:.3f} in mean return.",
        "",
        "## Training throughput (env steps/s, evaluation off)",
        "",
        "| path | learners x envs | env steps/s | ms per batched step | vs plain (table env) |",
        "|---|---:|---:|---:|---:|",
    ]
    base = results["throughput"]["plain_table"]
    lines.append(f"| plain Python, gymnasium's table | 1 x 1 | {base:,.0f} | | 1.00x |")
    gym = results["throughput"]["plain_gymnasium"]
    name = "plain Python, `gymnasium.make('Taxi-v4')`"
    lines.append(f"| {name} | 1 x 1 | {gym:,.0f} | | {ratio(gym / base)} |")
    for r in results["throughput"]["batched"]:
        lines.append(
            f"| batched | {r['learners']} x {r['envs']} | {r['steps_per_s']:,.0f} | "
            f"{r['ms_per_step']:.2f} | {ratio(r['steps_per_s'] / base)} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------- main
def parse(argv: list[str] | None) -> argparse.Namespace:
    """Command-line options."""
    p = argparse.ArgumentParser(description="Taxi MAXQ-Q: batched population vs plain Python.")
    p.add_argument("--quick", action="store_true", help="small smoke run (3 seeds, short)")
    p.add_argument("--seeds", type=int, default=None, help="number of seeds (default 10)")
    p.add_argument(
        "--envs", type=int, nargs="+", default=None, help="envs per learner to try (128 256 512)"
    )
    p.add_argument(
        "--eval-every", type=int, nargs="+", default=None, help="eval intervals (2048 8192)"
    )
    p.add_argument(
        "--repeat", type=int, default=1, help="runs per configuration; the fastest is kept"
    )
    p.add_argument("--max-steps", type=int, default=200_000, help="give up after (per learner)")
    p.add_argument("--sps-seconds", type=float, default=None, help="window per throughput row")
    p.add_argument("--json", default=None, help="also write the raw results here")
    p.add_argument(
        "--compile-step",
        action="store_true",
        help="batched trainers run their step compiled (TrainConfig.compile_step; the "
        "compile, tens of seconds per trainer, counts in the threshold runs' training time)",
    )
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the markdown report."""
    args = parse(argv)
    global COMPILE_STEP
    COMPILE_STEP = args.compile_step
    torch.set_num_threads(1)
    quick = args.quick
    n_seeds = args.seeds or (3 if quick else 10)
    envs = args.envs or ([256] if quick else [128, 256, 512])
    intervals = args.eval_every or ([8192] if quick else [2048, 8192])
    sps_seconds = args.sps_seconds or (0.3 if quick else 3.0)
    shapes = [(1, 1), (10, 512)] if quick else [(1, 1), (10, 1), (10, 256), (10, 512), (10, 2048)]
    seeds = list(range(n_seeds))
    results: dict = {
        "machine": machine(),
        "command": "python scripts/bench.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "n_seeds": n_seeds,
        "load": {"start": load()},
    }

    reference = make_trainer(seeds, envs[0])
    hyper = hyper_of(reference)
    results["hyper"] = asdict(hyper)
    results["eval_episodes"] = reference.config.eval_episodes
    threshold = results["threshold"] = reference.config.threshold
    starts = eval_starts(reference.config.eval_episodes)
    del reference

    # (a) and (b): batched grid, plain per interval
    warm_up(seeds)
    batched = []
    for k in intervals:
        for e in envs:
            run = min(
                (batched_to_threshold(seeds, e, k, args.max_steps) for _ in range(args.repeat)),
                key=lambda r: r.wall,
            )
            print(f"batched E={e} eval every {k}: {run.wall:.2f} s", file=sys.stderr)
            batched.append(run)
    plain = []
    for k in intervals:
        series = min(
            (
                plain_to_threshold(seeds, hyper, starts, k, threshold, args.max_steps)
                for _ in range(args.repeat)
            ),
            key=lambda r: r.wall,
        )
        print(f"plain eval every {k}: {series.wall:.2f} s", file=sys.stderr)
        plain.append(series)
    results["load"]["after_threshold"] = load()
    results["cross_check"] = cross_check(plain[0], starts)

    def reached_b(r: BatchedRun) -> bool:
        return None not in r.steps_to_threshold

    def reached_p(s: PlainSeries) -> bool:
        return all(r.steps_to_threshold is not None for r in s.runs)

    best_b = min(batched, key=lambda r: (not reached_b(r), r.wall))
    best_p = min(plain, key=lambda s: (not reached_p(s), s.wall))
    results["summary"] = {
        "batched_envs": best_b.envs,
        "batched_eval_every": best_b.eval_every,
        "batched_wall": best_b.wall,
        "batched_train": best_b.train,
        "plain_eval_every": best_p.eval_every,
        "plain_wall": best_p.wall,
        "plain_train": best_p.train,
        "speedup_wall": best_p.wall / best_b.wall,
        "speedup_train": best_p.train / best_b.train,
        "batched_all_reached": all(reached_b(r) for r in batched),
        "plain_all_reached": all(reached_p(s) for s in plain),
    }
    results["batched"] = [asdict(r) for r in batched]
    results["plain"] = [
        {
            "eval_every": s.eval_every,
            "wall": s.wall,
            "cpu": s.cpu,
            "train": s.train,
            "eval": s.eval,
            "runs": [r.summary() for r in s.runs],
        }
        for s in plain
    ]

    # (c) throughput
    throughput = {
        "plain_table": plain_maxq.steps_per_second(0, hyper, sps_seconds, TableTaxi()),
        "plain_gymnasium": plain_maxq.steps_per_second(0, hyper, sps_seconds, GymTaxi()),
        "batched": [],
    }
    for p_, e in shapes:
        sps, ms = batched_steps_per_second(p_, e, sps_seconds)
        throughput["batched"].append(
            {"learners": p_, "envs": e, "steps_per_s": sps, "ms_per_step": ms}
        )
    results["throughput"] = throughput
    results["load"]["end"] = load()

    text = report(results)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
