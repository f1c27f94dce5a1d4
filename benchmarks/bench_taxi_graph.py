"""Taxi MAXQ-Q training step on the CPU: eager, trace replay, compiled trace, side by side.

Three trainers of ``agents/taxi.py``'s ``maxq-q`` on the same seeds, in one process: the
eager step; ``StepGraph(backend="trace")`` (the recorded aten ops replayed from Python, the
CUDA-graph semantics on the CPU); ``TrainConfig.compile_step`` (those ops compiled by inductor
into one call, ``hrl_torch.training.trace_compile``). Blocks of training steps alternate between
them; the best block of each is reported in thread (CPU) seconds per step, with the eager / compiled
ratio, the compile time, and whether the learned tables (int32 bit patterns) and stacks of
the three are equal.

Run: ``python benchmarks/bench_taxi_graph.py`` (``--shapes 1x1 10x512``, ``--blocks 4``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # agents/, envs/, benchmarks/

from benchmarks import bench_taxi  # noqa: E402
from hrl_torch.training.cuda_graph import StepGraph  # noqa: E402


def _same(trainers) -> bool:
    tables = [t.learner.tables.store.view(torch.int32) for t in trainers]
    stacks = [t.executor.stack.inst for t in trainers]
    return all(torch.equal(tables[0], x) for x in tables) and all(
        torch.equal(stacks[0], x) for x in stacks
    )


def side_by_side(p: int, e: int, steps: int, blocks: int) -> dict:
    """Best thread seconds per step of the three ways, ``p`` learners x ``e`` envs."""
    seeds = list(range(p))
    eager, traced = bench_taxi.make_trainer(seeds, e, 0), bench_taxi.make_trainer(seeds, e, 0)
    bench_taxi.COMPILE_STEP = True
    compiled = bench_taxi.make_trainer(seeds, e, 0)
    bench_taxi.COMPILE_STEP = False
    trace = StepGraph(traced.train_step, traced, backend="trace")
    ways = {"eager": eager.train_step, "trace": trace, "compiled": compiled.train_step}
    for _ in range(trace.warmup):
        for way in ways.values():
            way()
    t0 = time.perf_counter()
    compiled.train_step()  # (the capture and the compile)
    compile_s = time.perf_counter() - t0
    eager.train_step()
    trace()
    best = dict.fromkeys(ways, 1e9)
    for _ in range(blocks):
        for name, way in ways.items():
            c0 = time.thread_time()
            for _ in range(steps):
                way()
            best[name] = min(best[name], (time.thread_time() - c0) / steps)
    return {
        "best": best,
        "compile_s": compile_s,
        "compiled": compiled._graph.failed is None and compiled._graph.graph is not None,
        "same": _same([eager, traced, compiled]),
    }


def main(argv: list[str] | None = None) -> int:
    """Print one markdown row per shape."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", nargs="+", default=["1x1", "10x8", "10x64", "10x512"])
    ap.add_argument("--blocks", type=int, default=4, help="alternating blocks per way")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    print(
        "| learners x envs | eager ms | trace replay ms | compiled ms | eager / compiled "
        "| compile s | compiled | tables + stacks equal |"
    )
    print("|---|---:|---:|---:|---:|---:|---|---|")
    for shape in args.shapes:
        p, e = (int(x) for x in shape.split("x"))
        r = side_by_side(p, e, max(20, 2000 // (p * e)), args.blocks)
        b = r["best"]
        print(
            f"| {p} x {e} | {1e3 * b['eager']:.3f} | {1e3 * b['trace']:.3f} | "
            f"{1e3 * b['compiled']:.3f} | {b['eager'] / b['compiled']:.2f}x | "
            f"{r['compile_s']:.0f} | {r['compiled']} | {r['same']} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
