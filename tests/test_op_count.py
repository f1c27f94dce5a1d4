"""Tensor ops per batched training step, counted (deterministic, unlike timings) and budgeted.

A batched step's cost on a CPU, and its kernel launches on a GPU, grow with the number of aten
ops it dispatches. The counts are a function of the code and the seeds alone, so a budget guards
speed in CI where wall-clock cannot. The budgets are today's counts plus about 5%; lower them
as the hot path gets leaner.
"""

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

import agents  # noqa: F401  (registers the domains)
from hrl_torch import registry
from hrl_torch.experiment import RunOptions, build_trainer

# (domain, algorithm, envs per learner): budget; measured counts in the comments
BUDGETS = {
    ("taxi", "maxq-q", 1): 540,  # 509 (862 before the core rewrite)
    ("small-agv", "har", 1): 680,  # 649 (1,050 before the core rewrite)
    ("ship-steering", "hybrid", 1): 1_200,  # 1,146 (1,568 before the ship domain's rewrite)
}


class OpCounter(TorchDispatchMode):
    """Counts every aten op dispatched inside its context."""

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.count += 1
        return func(*args, **(kwargs or {}))


def ops_per_step(domain: str, algo: str, envs: int, warmup: int = 30) -> list[int]:
    opts = RunOptions(seeds=[0], envs_per_learner=envs, progress=False, tensorboard=False)
    trainer = build_trainer(registry.get(domain), algo, opts)
    for _ in range(warmup):
        trainer.train_step()
    counts = []
    for _ in range(3):
        with OpCounter() as counter:
            trainer.train_step()
        counts.append(counter.count)
    return counts


@pytest.mark.parametrize("case", list(BUDGETS), ids=lambda c: f"{c[0]}-{c[1]}-x{c[2]}")
def test_ops_per_training_step_stay_within_budget(case):
    torch.set_num_threads(1)
    counts = ops_per_step(*case)
    assert max(counts) <= BUDGETS[case], f"{case}: {counts} aten ops per step"
    assert min(counts) > 0.5 * BUDGETS[case], "the budget is stale: lower it to the new count"
