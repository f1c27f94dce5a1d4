"""Does ``torch.compile`` pay on the CPU for taxi MAXQ-Q? Eager against compiled, in one process.

Two trainers of ``agents/taxi.py``'s ``maxq-q`` on the same seeds step side by side; in the
second, the pure-tensor parts named by ``--parts`` are wrapped by ``torch.compile`` (inductor,
static shapes): ``evaluate`` (the learner's bottom-up values, one graph with no breaks) and
``update`` (its table update). Blocks of training steps alternate between the two; the best
block of each is reported, in thread (CPU) seconds and in wall seconds, with the ratio, and the
learned tables must stay bit-identical. A part that fails to compile falls back to eager with
one warning (the run goes on, and says so).

Run: ``python benchmarks/bench_taxi_compile.py`` (``--help`` for options). The whole agent step
(``agent.decide``) is not tried: dynamo guards on the step counter and on the random-number
blocks (``BatchRNG``'s look-ahead), so it recompiles as they move (measured in
benchmarks/RESULTS.md).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # agents/, envs/, benchmarks/

from benchmarks.bench_taxi import make_trainer  # noqa: E402

PARTS = ("evaluate", "update")


def compiled(fn, name: str):
    """``torch.compile(fn)``, or ``fn`` itself with one warning if compiling fails."""
    state = {"fn": torch.compile(fn, dynamic=False), "failed": False}

    def call(*args, **kwargs):
        if not state["failed"]:
            try:
                return state["fn"](*args, **kwargs)
            except Exception as err:  # noqa: BLE001  (any compiler failure: run eager)
                state["failed"] = True
                warnings.warn(f"torch.compile of {name} failed, running eager: {err}", stacklevel=2)
        return fn(*args, **kwargs)

    call.state = state
    return call


def side_by_side(p: int, e: int, parts: list[str], steps: int, blocks: int) -> dict:
    """Eager and compiled trainers ``p x e``, alternating blocks of ``steps`` training steps."""
    eager, comp = make_trainer(list(range(p)), e, 0), make_trainer(list(range(p)), e, 0)
    wrapped = {}
    for part in parts:
        wrapped[part] = compiled(getattr(comp.learner, part), part)
        setattr(comp.learner, part, wrapped[part])
    t0 = time.perf_counter()
    for _ in range(3):
        comp.train_step()
    compile_s = time.perf_counter() - t0
    for _ in range(3):
        eager.train_step()
    best = {"eager": [1e9, 1e9], "compiled": [1e9, 1e9]}
    for _ in range(blocks):
        for name, trainer in (("eager", eager), ("compiled", comp)):
            w0, c0 = time.perf_counter(), time.thread_time()
            for _ in range(steps):
                trainer.train_step()
            wall, cpu = (time.perf_counter() - w0) / steps, (time.thread_time() - c0) / steps
            best[name] = [min(best[name][0], cpu), min(best[name][1], wall)]
    same = torch.equal(
        eager.learner.tables.store.view(torch.int32), comp.learner.tables.store.view(torch.int32)
    )
    failed = [k for k, f in wrapped.items() if f.state["failed"]]
    return {
        "shape": f"{p} x {e}",
        "best": best,
        "compile_s": compile_s,
        "same": same,
        "failed": failed,
    }


def main(argv: list[str] | None = None) -> int:
    """Print one markdown row per shape."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", nargs="+", default=list(PARTS), choices=PARTS)
    ap.add_argument("--blocks", type=int, default=5, help="alternating blocks per trainer")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    print(f"compiled: {', '.join(args.parts)}; best of {args.blocks} alternating blocks")
    print(
        "| learners x envs | eager ms/step (CPU / wall) | compiled ms/step (CPU / wall) "
        "| eager / compiled (CPU) | compile s | tables bit-identical |"
    )
    print("|---|---:|---:|---:|---:|---|")
    for p, e, steps in ((1, 1, 300), (10, 512, 20)):
        r = side_by_side(p, e, args.parts, steps, args.blocks)
        (ec, ew), (cc, cw) = r["best"]["eager"], r["best"]["compiled"]
        note = f" (fell back: {r['failed']})" if r["failed"] else ""
        print(
            f"| {r['shape']} | {1e3 * ec:.3f} / {1e3 * ew:.3f} | {1e3 * cc:.3f} / "
            f"{1e3 * cw:.3f} | {ec / cc:.2f}x | {r['compile_s']:.1f} | {r['same']}{note} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
