"""MAXQ-Q's all-states updating (Algorithm 4, lines 15-17 and 25-27) with shaping rewards,
against the update written out by hand on the scripted chain of
``test_hand_computed_targets`` (the root's ``Go2`` runs from 0 through 1 to 2)."""

import pytest
import torch

from hrl_torch.execution.executor import ExecutorConfig, HierarchicalExecutor
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError, Primitive, Subtask
from hrl_torch.learners import MaxQLearner
from hrl_torch.training.agent import with_values
from tests.learners.test_hand_computed_targets import (
    ALPHA,
    GAMMA,
    ROOT_SHAPING,
    STEPS,
    per_state_chain,
    reference_maxq,
    step,
)
from tests.learners.test_q_lambda_and_hh_exact import FirstAvailable


def run_all_states(graph, env, learner, steps):
    ex = HierarchicalExecutor(graph, 1, 1, gamma=GAMMA, config=ExecutorConfig(record_visited=4))
    policy = FirstAvailable()
    ctx = graph.context(env.reset())
    learner.evaluate(ctx)
    ex.act(ctx, policy, 0)
    for _ in range(steps):
        td = env.step(ex._action)
        ctx = graph.context(td)
        learner.evaluate(ctx)
        learner.update(with_values(ex.observe(td, ctx), ctx), 0)
        ex.act(ctx, policy, 0)


def reference_root_at_1(episodes=2):
    """``C(Root, 1, Go2)`` and ``C~``: the root's visited state 1, one step before ``Go2``
    ends in 2. Target ``gamma V(Root, 2)``; internal: the root's shaping from 1 on (one step:
    0.25, not the 0.25 + 0.9 * 0.25 of the whole child) plus ``gamma V~(Root, 2)``. The values
    at 2 are those before each episode's second step, as ``reference_maxq`` has them."""
    c, ci = {"r1": 0.0}, {"r1": 0.0}
    vr2, go3, go3i, root2, root2i = 0.0, 0.0, 0.0, 0.0, 0.0
    for _ in range(episodes):
        v_root2, v_root2_int = vr2 + go3 + root2, vr2 + go3 + root2i
        step(c, {"r1": GAMMA * v_root2})
        step(ci, {"r1": ROOT_SHAPING + GAMMA * v_root2_int})
        # the episode's last step: V(Right, 2) <- 10; Go3 and the root at 2 end terminal
        vr2 = (1 - ALPHA) * vr2 + ALPHA * 10.0
        go3, go3i = (1 - ALPHA) * go3, (1 - ALPHA) * go3i + ALPHA * 0.5
        root2, root2i = (1 - ALPHA) * root2, (1 - ALPHA) * root2i + ALPHA * ROOT_SHAPING
    return c["r1"], ci["r1"]


def test_all_states_updating_with_shaping_matches_the_hand_computation():
    graph, env = per_state_chain(internal_rewards=True)
    learner = MaxQLearner(graph, 1, alpha=ALPHA, gamma=GAMMA, all_states=True)
    run_all_states(graph, env, learner, STEPS)
    h = learner.heads
    external, internal = reference_root_at_1()
    assert abs(float(h["Root"]["C"][0, 1, 0]) - external) < 1e-5
    assert abs(float(h["Root"]["C_int"][0, 1, 0]) - internal) < 1e-5
    # the entries every update reaches are unchanged by all-states updating
    _, c, ci = reference_maxq()
    assert abs(float(h["Root"]["C"][0, 0, 0]) - c["root@0"]) < 1e-5
    assert abs(float(h["Root"]["C_int"][0, 0, 0]) - ci["root@0"]) < 1e-5
    # by hand, episode 1: C~(Root, 1, Go2) = 0.5 * 0.25 (all values at 2 still 0)
    assert internal > 0.5 * ROOT_SHAPING


def test_all_states_refused_where_an_internal_reward_reads_the_invocations_memory():
    sub = Subtask(
        "Go",
        ["Right"],
        remember=lambda o: o["observation"][:, None].float(),
        memory_size=1,
        pseudo_reward=lambda o, m: m[:, 0],
        terminated=lambda o, m: o["observation"] == 2,
    )
    nodes = [Subtask("Root", ["Go"]), sub, Primitive("Right", 0)]
    graph = TaskGraph("Root", nodes, n_actions=1)
    with pytest.raises(GraphError, match="where their invocation started"):
        MaxQLearner(graph, 1, all_states=True)
    MaxQLearner(graph, 1)  # fine without all-states updating
    assert torch.is_tensor(MaxQLearner(graph, 1).C.store)


def test_init_nodes_sets_the_initial_completions_of_the_named_subtasks_only():
    graph, _ = per_state_chain(internal_rewards=True)
    learner = MaxQLearner(graph, 2, init=-10.0, init_nodes={"Root": 0.0})
    h = learner.heads
    assert bool((h["Root"]["C"] == 0).all()) and bool((h["Root"]["C_int"] == 0).all())
    assert bool((h["Go2"]["C"] == -10).all()) and bool((h["Go3"]["C_int"] == -10).all())
    with pytest.raises(GraphError, match="not a subtask"):
        MaxQLearner(graph, 1, init_nodes={"Right": 0.0})
