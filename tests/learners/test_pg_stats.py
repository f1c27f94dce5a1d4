"""A PG subtask a user can debug: per-group scalars at each log (``pg_stats``), and the action
range taken from the env at the trainer's start."""

import math

import pytest
import torch

from hrl_torch.learners.pg import HPGRLLearner, PGConfig
from hrl_torch.modules.exploration import Greedy
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer
from tests.learners.test_pg_scores import HIGH, LOW, Reach, coder, gaussian_graph, two_level_graph


def _trained(steps: int = 60):
    torch.manual_seed(0)
    graph = gaussian_graph()
    learner = HPGRLLearner(graph, 2, PGConfig(alpha=0.05, sigma=0.8), coder=coder())
    env = Reach([0, 1], 8)
    trainer = Trainer(env, graph, learner, Greedy(), TrainConfig(steps=steps, eval_every=0))
    assert learner.heads["Root"].range() == (LOW, HIGH)  # from Reach.action_bounds
    for _ in range(steps):
        trainer.train_step()
    return trainer, learner


def test_a_gaussian_subtask_logs_returns_policy_and_update_norms():
    trainer, learner = _trained()
    out = learner.log_scalars(trainer.step)
    # Reach pays -|a - target| / 5 per step, episodes of 3: a return per invocation below 0
    returns = out["hrl/Root/return_per_invocation"]
    assert len(returns) == 2 and all(-20 < r < 0 for r in returns)
    moved, alpha = out["losses/Root/update_norm"], out["losses/Root/step_size"]
    assert alpha == [0.05, 0.05] and all(m > 0 for m in moved)
    assert out["losses/Root/gradient_norm"] == pytest.approx([m / 0.05 for m in moved])
    w = learner.params.block(0)[:, 0, :]
    assert out["hrl/Root/policy_spread"] == pytest.approx(w.std(-1, correction=0).tolist())
    assert all(LOW < a < HIGH for a in out["hrl/Root/policy_mean"])
    assert out["hrl/Root/policy_sigma"] == [0.8, 0.8]
    again = learner.log_scalars(trainer.step)  # the sums restart at each log
    assert all(math.isnan(r) for r in again["hrl/Root/return_per_invocation"])
    assert again["losses/Root/update_norm"] == [0.0, 0.0]


def test_a_softmax_subtask_logs_its_entropy():
    learner = HPGRLLearner(two_level_graph(), 2)
    out = learner.log_scalars(0)
    n = len(two_level_graph().node("Root").children_names)
    assert out["hrl/Root/policy_entropy"] == pytest.approx([math.log(n)] * 2)  # uniform at 0
