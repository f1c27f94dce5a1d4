"""Bad rewards, durations, abstractions and hyperparameters get a clear error, not bad tables."""

import re
from dataclasses import replace

import pytest
import torch

from envs.taxi import TaxiEnv
from hrl_torch.execution.executor import BadStepError, ExecutorConfig, HierarchicalExecutor
from hrl_torch.execution.transitions import LEVEL, PRIMITIVE
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError, Primitive, Subtask
from hrl_torch.learners import HARLearner, MaxQLearner, SMDPQLearner
from hrl_torch.learners.pg import HPGRLLearner, PGConfig
from hrl_torch.learners.q_lambda import QLambdaLearner
from tests.learners.test_q_lambda_and_hh_exact import FirstAvailable, chain


def step_with(reward: float, duration: float, config=None):
    graph, env = chain()
    ex = HierarchicalExecutor(graph, 1, 1, config=config)
    ctx = graph.context(env.reset())
    ex.act(ctx, FirstAvailable(), 0)
    td = env.step(ex._action)
    td["reward"][:] = reward
    td["duration"][:] = duration
    batch = ex.observe(td, graph.context(td))
    return ex, graph, td, batch


def test_a_skipped_bad_step_aborts_the_row_and_counts():
    ex, graph, td, batch = step_with(float("nan"), 1.0, ExecutorConfig(on_bad_step="skip"))
    assert ex.skipped_steps.tolist() == [1.0]
    assert not bool(batch[PRIMITIVE]["valid"].any())  # nothing to learn from the bad step
    assert not bool(batch[LEVEL]["valid"].any())
    assert ex.stack.top.tolist() == [-1]  # every running subtask aborted
    good, _, _, _ = step_with(-1.0, 1.0, ExecutorConfig(on_bad_step="skip"))
    assert good.skipped_steps.tolist() == [0.0] and bool(good.stack.top >= 0)
    ex.act(graph.context(td), FirstAvailable(), 1)  # the row starts again at the root
    fresh = HierarchicalExecutor(graph, 1, 1)
    fresh.act(graph.context(td), FirstAvailable(), 1)
    assert torch.equal(ex.stack.inst, fresh.stack.inst)


@pytest.mark.parametrize(
    "reward,duration,shown",
    [
        (float("inf"), 1.0, "reward inf and duration 1.0"),
        (float("nan"), 1.0, "reward nan and duration 1.0"),
        (-1.0, float("nan"), "reward -1.0 and duration nan"),
        (-1.0, -2.0, "reward -1.0 and duration -2.0"),
    ],
)
def test_non_finite_rewards_and_bad_durations_are_refused(reward, duration, shown):
    expected = f"env row 0 returned {shown} while 'Root/Go2/Right' ran: rewards must be finite"
    with pytest.raises(BadStepError, match=expected):
        step_with(reward, duration)


def test_a_float_abstraction_is_an_error_not_truncated():
    state = lambda o: o["observation"].float() / 2  # noqa: E731
    graph = TaskGraph(
        "Root", [Subtask("Root", ["a"], n_states=4, abstract=state), Primitive("a", 0)], 1
    )
    _, env = chain()
    with pytest.raises(GraphError, match="'Root'.abstract returned torch.float32 values"):
        graph.context(env.reset())


@pytest.mark.parametrize(
    "make,message",
    [
        (lambda g: MaxQLearner(g, 1, alpha=float("nan")), "MaxQLearner: alpha must be in (0, 1]"),
        (lambda g: MaxQLearner(g, 1, alpha=-1.0), "MaxQLearner: alpha must be in (0, 1]"),
        (lambda g: SMDPQLearner(g, 1, alpha=1.5), "SMDPQLearner: alpha must be in (0, 1]"),
        (lambda g: MaxQLearner(g, 1, gamma=1.5), "MaxQLearner: gamma must be in [0, 1]"),
        (lambda g: SMDPQLearner(g, 1, gamma=-0.1), "SMDPQLearner: gamma must be in [0, 1]"),
        (lambda g: HARLearner(g, 1, alpha=0.0), "HARLearner: alpha must be in (0, 1]"),
        (lambda g: QLambdaLearner(g, 1, lam=1.2), "QLambdaLearner: lam must be in [0, 1]"),
        (lambda g: HPGRLLearner(g, 1, PGConfig(alpha=-0.1)), "HPGRLLearner: alpha must be > 0"),
    ],
)
def test_hyperparameters_out_of_range_are_refused(make, message):
    graph, _ = chain()
    with pytest.raises(ValueError, match=re.escape(message)):
        make(graph)


class SometimesNaN(TaxiEnv):
    """Taxi whose Pickup returns a NaN reward in every 7th state."""

    def _step_all(self, action):
        before = self.state
        reward, duration, terminated = super()._step_all(action)
        bad = (action == 4) & (before % 7 == 0)
        return reward.masked_fill(bad, float("nan")), duration, terminated


def test_skipping_bad_steps_trains_on_the_rest(tmp_path):
    import agents  # noqa: F401  (registers the domains)
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer
    from hrl_torch.training.runlog import RunLogger

    taxi = registry.get("taxi")
    spec = replace(taxi.algos["maxq-q"], executor=ExecutorConfig(on_bad_step="skip"))
    domain = replace(taxi, algos={"maxq-q": spec}, make_env=lambda s, e, b: SometimesNaN(s, e))
    logger = RunLogger(tmp_path, [0, 1], {}, tensorboard=False)
    opts = RunOptions(seeds=[0, 1], envs_per_learner=64, steps=30_000, progress=False)
    trainer = build_trainer(domain, "maxq-q", opts, logger)
    result = trainer.train()
    assert all(bool(t.isfinite().all()) for t in trainer.learner.state_dict().values())
    skipped = trainer.executor.skipped_steps
    assert bool((skipped > 0).all()), skipped
    # taxi still learned: the optimum is 7.5 (a little more where a -1 Pickup was skipped)
    assert all(v >= 7.5 for v in result.final_eval), result.final_eval
    logged = (tmp_path / "progress.csv").read_text()
    assert ",charts/skipped_steps," in logged and ",nan" not in logged


def test_a_learner_with_the_wrong_number_of_table_sets_is_refused():
    from agents.taxi import taxi_hierarchy
    from hrl_torch.modules.exploration import Greedy
    from hrl_torch.training.trainer import Trainer

    graph = taxi_hierarchy()
    learner = MaxQLearner(graph, n_learners=3)
    with pytest.raises(ValueError, match="learner has 3 table sets, the env needs 2"):
        Trainer(TaxiEnv([0, 1], envs_per_learner=4), graph, learner, Greedy())
