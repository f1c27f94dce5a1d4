"""Bad rewards, durations, abstractions and hyperparameters get a clear error, not bad tables."""

import re

import pytest

from hrl_torch.executor import HierarchicalExecutor
from hrl_torch.graph import GraphError, Primitive, Subtask, TaskGraph
from hrl_torch.learners import HARLearner, MaxQLearner, SMDPQLearner
from hrl_torch.learners.pg import HPGRLLearner, PGConfig
from hrl_torch.learners.q_lambda import QLambdaLearner
from tests.learners.test_q_lambda_and_hh_exact import FirstAvailable, chain


def step_with(reward: float, duration: float):
    graph, env = chain()
    ex = HierarchicalExecutor(graph, 1, 1)
    ctx = graph.context(env.reset())
    ex.act(ctx, FirstAvailable(), 0)
    td = env.step(ex._action)
    td["reward"][:] = reward
    td["duration"][:] = duration
    ex.observe(td, graph.context(td))


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
    with pytest.raises(ValueError, match=f"env row 0 returned {shown}: rewards must be finite"):
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
