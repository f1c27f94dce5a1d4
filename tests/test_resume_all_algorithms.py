"""Exact resume for every registered domain and algorithm: train, save mid-episode, load into a
fresh trainer, continue; tables, Task-Stacks, RNG streams, curves and logged rows equal one
uninterrupted run's."""

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch import registry
from hrl_torch.experiment import RunOptions, build_trainer

HALF = 160  # env steps per learner before the checkpoint (40 batched steps: mid-episode)
CASES = [(d, a) for d in registry.names() for a in sorted(registry.get(d).algos)]


class MemoryLogger:
    """Keeps every logged row (timings left out)."""

    def __init__(self) -> None:
        self.rows: list[tuple] = []

    def log(self, step: int, per_seed: dict) -> None:
        for key, values in sorted(per_seed.items()):
            if not key.startswith("perf/"):
                self.rows.append((step, key, repr([float(v) for v in values])))


def make(domain: str, algo: str, logger: MemoryLogger):
    opts = RunOptions(
        seeds=[0, 1],
        envs_per_learner=4,
        steps=2 * HALF,
        eval_every=HALF,
        eval_episodes=2,
        progress=False,
        tensorboard=False,
    )
    trainer = build_trainer(registry.get(domain), algo, opts, logger)
    trainer.config.eval_max_steps = 30
    trainer.config.log_every = HALF // 4
    if trainer.evaluator is not None:  # continuing tasks: a short throughput evaluation
        trainer.evaluator.horizon, trainer.evaluator.burn_in = 20, 5
    return trainer


def flatten(prefix: str, value, out: dict) -> dict:
    if isinstance(value, dict):
        for k, v in value.items():
            flatten(f"{prefix}.{k}", v, out)
    else:
        out[prefix] = value
    return out


def state_of(trainer) -> dict:
    """Every tensor a continuation depends on, flattened to ``{name: tensor}``."""
    flat = flatten("learner", dict(trainer.learner.state_dict()), {})
    flatten("executor", trainer.executor.state_dict(), flat)
    flatten("env", trainer.env.state_dict(), flat)
    for name, buf in trainer.learner.named_buffers():  # the banks the heads are views of
        flat[f"buffer.{name}"] = buf
    flat["real_steps"] = trainer.real_steps
    return flat


@pytest.mark.parametrize("domain,algo", CASES, ids=[f"{d}-{a}" for d, a in CASES])
def test_a_resumed_run_equals_an_uninterrupted_one(domain, algo, tmp_path):
    torch.set_num_threads(1)
    straight_log, first_log, resumed_log = MemoryLogger(), MemoryLogger(), MemoryLogger()
    straight = make(domain, algo, straight_log)
    straight.train()
    first = make(domain, algo, first_log)
    first.train(steps=HALF)
    assert bool((first.executor.stack.top > 0).any()), "checkpoint at a subtask boundary"
    first.save(tmp_path / "ckpt.pt")
    resumed = make(domain, algo, resumed_log)
    resumed.load(tmp_path / "ckpt.pt")
    resumed.train()
    a, b = state_of(straight), state_of(resumed)
    assert a.keys() == b.keys()
    for key in a:
        same = torch.equal(a[key], b[key]) if torch.is_tensor(a[key]) else a[key] == b[key]
        assert same, key
    assert straight.curve == resumed.curve
    assert straight.policy.rng.state_dict() == resumed.policy.rng.state_dict()
    assert straight_log.rows == first_log.rows + resumed_log.rows
