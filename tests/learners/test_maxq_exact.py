"""MAXQ-Q tables after a tiny scripted run equal the hand-computed values of Dietterich's rules."""

import torch

from hrl_torch.execution.executor import HierarchicalExecutor
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner
from hrl_torch.training.agent import with_values
from tests.helpers import TableEnv


class AlwaysFirst:
    """A scripted policy: always the first child."""

    def new_step(self):
        pass

    def select(self, inst, ctx, available, step, push):
        return torch.zeros_like(inst), torch.ones_like(inst, dtype=torch.bool)


def chain_env():
    # states 0 -> 1 -> 2 -> 3 (terminal); -1 per step, +10 for entering 3
    next_state = torch.tensor([[1], [2], [3], [3]])
    reward = torch.tensor([[-1.0], [-1.0], [10.0], [0.0]])
    terminal = torch.tensor([False, False, False, True])
    return TableEnv(next_state, reward, terminal, torch.tensor([0]))


def test_two_scripted_episodes_give_the_hand_computed_tables():
    state = lambda o: o["observation"]  # noqa: E731
    go = Subtask("Go", ["Right"], n_states=4, abstract=state)
    graph = TaskGraph(
        "Root", [Subtask("Root", ["Go"]), go, Primitive("Right", 0, 4, state)], n_actions=1
    )
    learner = MaxQLearner(graph, 1, alpha=0.5, gamma=0.9)
    env = chain_env()
    ex = HierarchicalExecutor(graph, 1, 1, gamma=0.9)
    policy = AlwaysFirst()
    ctx = graph.context(env.reset())
    learner.evaluate(ctx)
    ex.act(ctx, policy, 0)
    for _ in range(7):  # 3 steps, 1 auto-reset, 3 steps
        td = env.step(ex._action)
        ctx = graph.context(td)
        learner.evaluate(ctx)
        learner.update(with_values(ex.observe(td, ctx), ctx), 0)
        ex.act(ctx, policy, 0)
    # episode 1: V(Right) <- 0.5 r; every C target is 0 (V and C still 0, or terminal)
    # episode 2: C(Go,0,R) <- 0.5 * 0.9 * (V(R,1) + C(Go,1,R)) = 0.45 * -0.5
    #            C(Go,1,R) <- 0.5 * 0.9 * (V(R,2) + C(Go,2,R)) = 0.45 * 5
    c_go = learner.C.view(graph.index["Go"])[:, 0]
    v_right = learner.V.view(graph.index["Right"])[:, 0]
    torch.testing.assert_close(c_go, torch.tensor([-0.225, 2.25, 0.0, 0.0]))
    torch.testing.assert_close(v_right, torch.tensor([-0.75, -0.75, 7.5, 0.0]))
    assert float(learner.C.view(graph.index["Root"])[0, 0]) == 0.0  # terminal targets only
