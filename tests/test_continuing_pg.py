"""Policy-gradient and hybrid learners on a continuing task: the throughput evaluation acts with
the learner's own policy (its heads' modes), not with action values it does not have."""

import torch

from agents.small_agv import make_env, small_agv_hierarchy, weighted_deliveries
from hrl_torch.learners import HPGRLLearner, PGConfig, PGPolicy, SMDPQLearner
from hrl_torch.learners.hybrid import HybridLearner, HybridPolicy
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.continuing import ThroughputEvaluator
from hrl_torch.training.trainer import Trainer


def run(make_learner, steps: int) -> Trainer:
    graph = small_agv_hierarchy()
    config = TrainConfig(steps=steps, eval_every=0, eval_episodes=2, progress=False)
    # (a short window: what is checked is which policy acts, not how well)
    evaluator = ThroughputEvaluator(horizon=100, burn_in=20, metric=weighted_deliveries)
    trainer = Trainer(
        make_env([0, 1], 8),
        graph,
        make_learner(graph),
        EpsilonGreedy(0.1),
        config,
        eval_env=make_env([5, 5], 2),
        evaluator=evaluator,
    )
    trainer.train()
    return trainer


def test_hpgrl_on_a_continuing_task_evaluates_with_its_policy_modes():
    trainer = run(lambda g: HPGRLLearner(g, 2, PGConfig(alpha=0.02)), 400)
    before = trainer.learner.theta.clone()
    throughput, rate = trainer.evaluate()
    assert torch.isfinite(throughput).all() and torch.isfinite(rate).all()
    assert torch.equal(trainer.learner.theta, before)
    agent = trainer.evaluation_agent(trainer.eval_env, "eval-explore")
    assert isinstance(agent.policy, PGPolicy) and agent.policy.greedy  # the heads' modes


def test_hybrid_on_a_continuing_task_evaluates():
    def hybrid(g):
        value = SMDPQLearner(g, 2)
        pg = HPGRLLearner(g, 2, PGConfig(alpha=0.02), nodes=["NavM1", "NavM2", "NavG1", "NavG2"])
        return HybridLearner(g, 2, value, pg)

    trainer = run(hybrid, 400)
    throughput, _ = trainer.evaluate()
    assert torch.isfinite(throughput).all()
    agent = trainer.evaluation_agent(trainer.eval_env, "eval-explore")
    assert isinstance(agent.policy, HybridPolicy) and agent.policy.greedy
