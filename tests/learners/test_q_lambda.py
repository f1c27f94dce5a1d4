"""Q(lambda) with replacing traces equals a plain Watkins Q(lambda) replaying the same episodes."""

import torch

from agents.taxi import flat_graph
from hrl_torch.common.rng import BatchRNG
from hrl_torch.execution.executor import HierarchicalExecutor
from hrl_torch.learners.base import ValuePolicy
from hrl_torch.learners.q_lambda import QLambdaLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.training.agent import with_values
from tests.helpers import random_table_env

S, A = 6, 3
ALPHA, LAM, GAMMA = 0.3, 0.8, 0.9


def reference_q_lambda(transitions):
    """Sutton & Barto's Watkins Q(lambda) with replacing traces (other actions of s cleared)."""
    q, e = torch.zeros(S, A, dtype=torch.float64), torch.zeros(S, A, dtype=torch.float64)
    for s, a, r, s2, terminal, greedy, end in transitions:
        if not greedy:
            e.zero_()
        e[s] = 0.0
        e[s, a] = 1.0
        target = r + (0.0 if terminal else GAMMA * q[s2].max())
        q += ALPHA * (target - q[s, a]) * e
        e *= GAMMA * LAM
        if end:
            e.zero_()
    return q


def test_q_lambda_equals_watkins_reference():
    seeds = [3, 8, 21]
    env = random_table_env(S, A, seed=1, terminal_frac=0.2, seeds=seeds, max_episode_steps=25)
    graph = flat_graph(S, A)
    learner = QLambdaLearner(graph, len(seeds), ALPHA, LAM, GAMMA, trace_len=32)
    executor = HierarchicalExecutor(graph, len(seeds), 1, GAMMA)
    policy = ValuePolicy(learner, EpsilonGreedy(0.3), BatchRNG(seeds, 1, "explore"))
    rows = env.learner_of_row()
    ctx = graph.context(env.reset(), rows)
    learner.evaluate(ctx)
    action = executor.act(ctx, policy, 0)
    seen = [[] for _ in seeds]
    for _ in range(600):
        td = env.step(action)
        ctx = graph.context(td, rows)
        learner.evaluate(ctx)
        batch = executor.observe(td, ctx)
        learner.update(with_values(batch, ctx), 0)
        for p in range(len(seeds)):
            if batch["level", "valid"][p, 0]:
                end = bool(batch["level", "terminal"][p, 0] or batch["level", "truncated"][p, 0])
                seen[p].append(
                    (
                        int(batch["level", "state"][p, 0]),
                        int(batch["level", "child"][p, 0]),
                        float(batch["level", "reward"][p, 0]),
                        int(batch["level", "next_state"][p, 0]),
                        bool(batch["level", "terminal"][p, 0]),
                        bool(batch["level", "greedy"][p, 0]),
                        end,
                    )
                )
        action = executor.act(ctx, policy, 0)
    for p in range(len(seeds)):
        ours = learner.Q.view(0, p)
        assert sum(not t[5] for t in seen[p]) > 20  # exploratory choices cut traces
        assert sum(t[6] for t in seen[p]) > 10  # episodes ended, by termination or time limit
        assert torch.allclose(ours.double(), reference_q_lambda(seen[p]), atol=1e-4)


def test_same_step_updates_of_one_entry_are_a_trace_weighted_mean():
    # two rows of one learner update the same pair in the same step: the step is alpha times
    # the mean TD error, not the sum
    graph = flat_graph(S, A)
    learner = QLambdaLearner(graph, 1, alpha=0.5, lam=0.0)
    index = torch.tensor([[4], [4]])
    learner._add(index, torch.tensor([[2.0], [4.0]]), torch.tensor([[1.0], [1.0]]), 0.5)
    assert learner.Q.data.view(-1)[4] == 0.5 * 3.0
