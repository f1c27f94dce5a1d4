"""Taxi MAXQ-Q learned state as bit patterns: save it on one checkout, compare on another.

For 1 x 1 (400 steps), 2 x 3 (400), 10 x 64 (150) and 3 x 1,100 (12) learners x envs: every
learner buffer (tables as int32 bit patterns, TD statistics), the training stacks' fields, the
next actions, and the greedy evaluation (means, success, lengths) half-way and at the end.

    cd <old checkout> && PYTHONPATH=$PWD python <this file> save /tmp/ref.pt
    cd <new checkout> && PYTHONPATH=$PWD python <this file> cmp /tmp/ref.pt

(run from the checkout's root: it imports the code there). ``cmp`` exits 1 on any difference.
"""

from __future__ import annotations

import sys

import torch

sys.path.insert(0, ".")  # the checkout being measured (run from its root)

from benchmarks.bench_taxi import make_trainer  # noqa: E402

SHAPES = ((1, 1, 400), (2, 3, 400), (10, 64, 150), (3, 1100, 12))


def evaluation(trainer) -> torch.Tensor:
    """Mean return, success rate and episode length per learner."""
    mean, success = trainer.evaluate()
    return torch.cat([mean, success, trainer.last_eval_steps.float()])


def state() -> dict:
    """Everything compared, keyed by ``(P, E, name)``."""
    out = {}
    for p, e, steps in SHAPES:
        trainer = make_trainer(list(range(p)), e, eval_episodes=20)
        for i in range(steps):
            trainer.train_step()
            if i == steps // 2:
                out[(p, e, "eval_mid")] = evaluation(trainer)
        out[(p, e, "eval")] = evaluation(trainer)
        for name, t in trainer.learner.state_dict().items():
            bits = t.float().view(torch.int32) if t.is_floating_point() else t
            out[(p, e, name)] = bits.clone()
        for key in ("inst", "reward", "steps", "start_state"):
            out[(p, e, "stack_" + key)] = getattr(trainer.executor.stack, key).clone()
        out[(p, e, "action")] = trainer.source.action.clone()
    return out


def main() -> int:
    torch.set_num_threads(1)
    mode, path = sys.argv[1], sys.argv[2]
    now = state()
    if mode == "save":
        torch.save(now, path)
        print(f"saved {len(now)} tensors")
        return 0
    ref = torch.load(path)
    bad = [k for k in ref if k not in now or not torch.equal(ref[k], now[k])]
    print(f"{len(ref)} tensors compared, {len(bad)} differ {bad[:10]}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
