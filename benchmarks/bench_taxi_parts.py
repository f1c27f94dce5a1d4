"""Taxi MAXQ-Q on the CPU, part by part: what the 10-seed threshold run spends its time on.

Thread (CPU) seconds, best of several blocks, one process: the training step at 1 x 1 and
10 x 512, the greedy evaluation of the 10 x 512 population at 8,192 env steps per learner
(every episode of every seed runs to the 200-step limit there: 200 steps of 1,000 rows) and at
16,384 (most episodes end; 15 rows loop), and aten ops per training and evaluation step. It
uses ``benchmarks.bench_taxi.make_trainer`` and ``Trainer.evaluate`` only, so the same file
measures an older checkout too: ``PYTHONPATH=<checkout> python benchmarks/bench_taxi_parts.py``
(run two checkouts in turn, several times: the machine is shared).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # agents/, envs/, benchmarks/

from benchmarks.bench_taxi import make_trainer  # noqa: E402


class _Ops(TorchDispatchMode):
    """Counts the aten ops dispatched inside."""

    def __init__(self) -> None:
        super().__init__()
        self.n = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.n += 1
        return func(*args, **(kwargs or {}))


def best_thread_seconds(fn, blocks: int, repeat: int = 1) -> float:
    """Best of ``blocks`` blocks of ``repeat`` calls, thread seconds per call."""
    best = float("inf")
    for _ in range(blocks):
        t0 = time.thread_time()
        for _ in range(repeat):
            fn()
        best = min(best, (time.thread_time() - t0) / repeat)
    return best


def step_part(p: int, e: int, steps: int) -> tuple[float, float]:
    """Training step: thread ms and aten ops per step, ``p`` learners x ``e`` envs."""
    trainer = make_trainer(list(range(p)), e, eval_episodes=0)
    for _ in range(20):
        trainer.train_step()
    ms = 1e3 * best_thread_seconds(trainer.train_step, 5, steps)
    with _Ops() as ops:
        for _ in range(steps):
            trainer.train_step()
    return ms, ops.n / steps


def eval_parts() -> list[tuple[int, float, float]]:
    """``(step, thread ms, ops per env step)`` of an evaluation at 8,192 and 16,384."""
    trainer = make_trainer(list(range(10)), 512)
    out = []
    for at in (8192, 16384):
        while trainer.step < at:
            trainer.train_step()
        trainer.evaluate()
        ms = 1e3 * best_thread_seconds(trainer.evaluate, 3)
        with _Ops() as ops:
            trainer.evaluate()
        out.append((at, ms, ops.n / trainer.last_eval_records["length"].max().item()))
    return out


def main() -> None:
    torch.set_num_threads(1)
    parts = [f"train {p}x{e} {ms:.3f} ms ({n:.0f} ops)" for p, e, s in ((1, 1, 300), (10, 512, 15))
             for ms, n in [step_part(p, e, s)]]  # fmt: skip
    parts += [f"eval@{at} {ms:.1f} ms ({n:.0f} ops/step)" for at, ms, n in eval_parts()]
    print(" | ".join(parts), flush=True)


if __name__ == "__main__":
    main()
