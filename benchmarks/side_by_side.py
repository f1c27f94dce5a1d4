"""Two versions of hrl-torch timed side by side: a training run and a greedy evaluation.

    git worktree add /tmp/bf82 bf82c46 && git worktree add /tmp/old38 11345d5
    PYTHONPATH=. .venv/bin/python benchmarks/side_by_side.py train --old /tmp/bf82 --rounds 2
    PYTHONPATH=. .venv/bin/python benchmarks/side_by_side.py eval --old /tmp/old38 --steps 3000
    PYTHONPATH=. .venv/bin/python benchmarks/side_by_side.py hashes

- ``train``: ``hrl-torch train trash --algo cooperative --seeds 5 --steps 60000
  --eval-episodes 0`` (issue 38's case) in the old checkout and in this one, alternately
  (``--rounds`` times each, so both see the same machine load); prints each run's
  ``train_seconds`` (summary.json) and the ratio of the medians. A checkout from before
  0.2.0's subpackages (``hrl_torch/cli.py``) runs as ``python -m hrl_torch.cli``.
- ``eval``: ``four-agv`` Cooperative HRL trained 2,000 steps (1 seed), then one greedy
  throughput evaluation capped at ``--steps`` event steps, in each checkout (0.1's flat
  layout and its ``four-agv-text`` name too); prints its wall and CPU seconds and its numbers.
- ``ops``: aten ops per greedy evaluation step of the same four-agv run (200 steps), in
  each checkout (deterministic, unlike the seconds on a shared machine).
- ``hashes``: SHA-256 of the learner's tables after 80 steps (2 seeds x 4 envs) of every
  cooperative configuration, to compare across commits.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: what both scripts start with: either layout, either name of the text's four AGVs
PRELUDE = r"""
import torch
torch.set_num_threads(1)
import agents  # noqa: F401
try:
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer
except ImportError:  # (0.1's flat layout, e.g. f3a1bd5)
    from hrl_torch import registry
    from hrl_torch.experiment import RunOptions, build_trainer
try:  # (0.1 called the text's set-up four-agv-text)
    DOMAIN = registry.get("four-agv-text")
except Exception:
    DOMAIN = registry.get("four-agv")
"""

EVAL = r"""
import json, sys, time, torch
""" + PRELUDE + r"""
opts = RunOptions(seeds=[0], steps=2000, progress=False, tensorboard=False, check_env=False)
trainer = build_trainer(DOMAIN, "cooperative", opts)
trainer.eval_env, eval_env = None, trainer.eval_env  # train only
trainer.train()
trainer.eval_env = eval_env
trainer.evaluator.max_steps = int(sys.argv[1])
trainer.evaluator.burn_in_time = 0.0  # (a capped window that counts from the start)
start, cpu = time.perf_counter(), time.process_time()
values = trainer.evaluator.evaluate(trainer)
seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
print(json.dumps({"seconds": seconds, "cpu": cpu, "values": repr([v.tolist() for v in values])}))
"""

OPS = r"""
import torch
from torch.utils._python_dispatch import TorchDispatchMode
""" + PRELUDE + r"""
class Count(TorchDispatchMode):
    count = 0
    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.count += 1
        return func(*args, **(kwargs or {}))
opts = RunOptions(seeds=[0], steps=200, progress=False, tensorboard=False, check_env=False)
trainer = build_trainer(DOMAIN, "cooperative", opts)
trainer.eval_env, eval_env = None, trainer.eval_env
trainer.train()
trainer.eval_env = eval_env
trainer.evaluator.max_steps = 200
with Count() as counter:
    trainer.evaluator.evaluate(trainer)
print(counter.count / 200)
"""

HASHES = r"""
import hashlib, torch
torch.set_num_threads(1)
import agents  # noqa: F401
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer
for domain, algo in [("trash", "cooperative"), ("two-taxi-earlier", "cooperative"),
                     ("two-taxi-earlier", "com-1"), ("four-agv-earlier", "cooperative"),
                     ("four-agv", "cooperative")]:
    opts = RunOptions(seeds=[0, 1], envs_per_learner=4, progress=False, check_env=False)
    opts.eval_episodes = 0
    trainer = build_trainer(registry.get(domain), algo, opts)
    for _ in range(80):
        trainer.train_step()
    h = hashlib.sha256()
    for key, value in sorted(trainer.learner.state_dict().items()):
        h.update(key.encode())
        h.update(value.detach().cpu().contiguous().numpy().tobytes())
    print(domain, algo, h.hexdigest()[:16])
"""


def _env(checkout: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(checkout), "RL_LOGGING_LEVEL": "WARNING"}


def train_seconds(checkout: Path, steps: int) -> float:
    """``train_seconds`` of issue 38's trash run in ``checkout``."""
    flat = (checkout / "hrl_torch" / "cli.py").exists()
    module = "hrl_torch.cli" if flat else "hrl_torch.runs.cli"
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", module, "train", "trash", "--algo", "cooperative"]
        cmd += ["--seeds", "5", "--steps", str(steps), "--eval-episodes", "0", "--out", out]
        cmd += ["--no-progress", "--no-tensorboard"]
        subprocess.run(cmd, cwd=checkout, env=_env(checkout), check=True, capture_output=True)
        (summary,) = Path(out).glob("*/summary.json")
        return float(json.loads(summary.read_text())["train_seconds"])


def greedy_evaluation(checkout: Path, steps: int) -> dict:
    """Seconds and numbers of one capped four-agv greedy evaluation in ``checkout``."""
    cmd = [sys.executable, "-c", EVAL, str(steps)]
    out = subprocess.run(cmd, cwd=checkout, env=_env(checkout), check=True, capture_output=True)
    return json.loads(out.stdout.decode().strip().splitlines()[-1])


def main() -> None:
    """Parse the arguments and print the comparison."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=["train", "eval", "ops", "hashes"])
    parser.add_argument("--old", type=Path, help="the other checkout (a git worktree)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--steps", type=int, default=None)
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    if args.what == "hashes":
        subprocess.run([sys.executable, "-c", HASHES], cwd=ROOT, env=_env(ROOT), check=True)
        return
    sides = {"old": args.old, "new": ROOT}
    if args.what == "ops":
        for name, checkout in sides.items():
            cmd = [sys.executable, "-c", OPS]
            out = subprocess.run(cmd, cwd=checkout, env=_env(checkout), capture_output=True)
            print(f"{name} ({checkout}): {out.stdout.decode().split()[-1]} ops per eval step")
        return
    if args.what == "train":
        times: dict[str, list[float]] = {"old": [], "new": []}
        for _ in range(args.rounds):
            for name, checkout in sides.items():
                times[name].append(train_seconds(checkout, args.steps or 60_000))
                print(f"{name} ({checkout}): train_seconds {times[name][-1]:.1f}", flush=True)
        ratio = statistics.median(times["new"]) / statistics.median(times["old"])
        print(f"new / old (medians): {ratio:.2f}")
    else:
        results = {name: greedy_evaluation(c, args.steps or 3_000) for name, c in sides.items()}
        for name, r in results.items():
            print(
                f"{name} ({sides[name]}): {r['seconds']:.1f} s ({r['cpu']:.1f} s CPU), "
                f"numbers {r['values']}"
            )
        same = results["old"]["values"] == results["new"]["values"]
        speedup = results["old"]["seconds"] / results["new"]["seconds"]
        print(f"old / new: {speedup:.2f}x, same numbers: {same}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
