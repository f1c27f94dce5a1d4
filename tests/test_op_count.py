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
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer

# (domain, algorithm, envs per learner): budget; measured counts in the comments. At one env
# per learner no two rows share a table, so the tables take the plain update (fewer ops);
# the x8 cases guard the grouped update of rows that may hit one entry.
BUDGETS = {
    # (+10: the deferred checks of a step with no host read, hrl_torch.training.deferred: 195
    # before)
    ("taxi", "maxq-q", 1): 215,  # 205 (509 at 1ce5127, 862 before the core rewrite)
    ("taxi", "maxq-q", 8): 229,  # 218
    ("small-agv", "har", 1): 360,  # 344 (647 at 1ce5127)
    ("small-agv", "har", 8): 372,  # 355
    # (+79: every row's PG choice and memory-feature start computed, no compaction: 1,082)
    ("ship-steering-earlier", "hybrid", 1): 1_180,  # 1,161 (1,568 at 1ce5127)
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


# a greedy evaluation step (no transitions: no sums kept, no transition masks;
# hrl_torch.execution.executor ``sums``; while every row loops, no root decision to record and no
# episode end to account): taxi MAXQ-Q, 4 episodes that all run to the time limit
EVAL_BUDGET = 116  # 110: 104 + the loop ring of issue 33 (hrl_torch.training.loops; 145 before
# the evaluation agents kept no sums)


def test_ops_per_greedy_evaluation_step_stay_within_budget(monkeypatch):
    from hrl_torch.training.evaluation import EvalEpisodes

    torch.set_num_threads(1)
    opts = RunOptions(
        seeds=[0], envs_per_learner=8, eval_episodes=4, progress=False, tensorboard=False
    )
    trainer = build_trainer(registry.get("taxi"), "maxq-q", opts)
    for _ in range(100):
        trainer.train_step()
    trainer.evaluate()
    steps, add = [0], EvalEpisodes.add

    def counted(self, *args):
        steps[0] += 1
        return add(self, *args)

    monkeypatch.setattr(EvalEpisodes, "add", counted)
    with OpCounter() as counter:
        trainer.evaluate()
    assert steps[0] == 200, "the episodes should run to the time limit (the count is per step)"
    per_step = counter.count / steps[0]
    assert EVAL_BUDGET / 2 < per_step <= EVAL_BUDGET, f"{per_step:.1f} aten ops per evaluation step"
