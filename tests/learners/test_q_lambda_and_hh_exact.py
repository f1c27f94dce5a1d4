"""Q(lambda) over multi-step children, HH-learning's model and gain, and the three-part
decomposition's choices and ``W``, against hand-computed values on a four-state chain
(0 -> 1 -> 2 -> 3, -1 per step, +10 for entering the terminal 3).

The root chooses between ``Go2`` (runs to state 2: two steps from 0) and ``Go3`` (runs to 3);
a scripted policy takes the first available child, so every episode is Go2 from 0 (two steps),
then Go3 from 2 (one step).
"""

import torch

from hrl_torch.execution.executor import HierarchicalExecutor
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import HDRLearner, HHLearner
from hrl_torch.learners.q_lambda import QLambdaLearner
from hrl_torch.training.agent import with_values
from tests.helpers import TableEnv


class FirstAvailable:
    def new_step(self):
        pass

    def select(self, inst, ctx, available, step, push):
        return available.float().argmax(-1), torch.ones_like(inst, dtype=torch.bool)


def chain():
    state = lambda o: o["observation"]  # noqa: E731
    nodes = [
        Subtask("Root", ["Go2", "Go3"], n_states=4, abstract=state),
        Subtask("Go2", ["Right"], terminated=lambda o: o["observation"] == 2),
        Subtask("Go3", ["Right"], terminated=lambda o: o["observation"] == 3),
        Primitive("Right", 0, 4, state),
    ]
    env = TableEnv(
        torch.tensor([[1], [2], [3], [3]]),
        torch.tensor([[-1.0], [-1.0], [10.0], [0.0]]),
        torch.tensor([False, False, False, True]),
        torch.tensor([0]),
    )
    return TaskGraph("Root", nodes, n_actions=1), env


def run(graph, env, learner, steps, gamma=1.0):
    ex = HierarchicalExecutor(graph, 1, 1, gamma=gamma)
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
    return ctx


def test_q_lambda_discounts_a_multi_step_child_by_gamma_to_the_n():
    graph, env = chain()
    learner = QLambdaLearner(graph, 1, alpha=0.5, lam=0.0, gamma=0.9, nodes=["Root"])
    run(graph, env, learner, 3 + 1 + 3, gamma=0.9)  # episode, auto-reset step, episode
    q = learner.heads["Root"]["Q"][0]
    # episode 1: Q(2, Go3) <- 0.5 * 10 = 5 (terminal); Q(0, Go2) <- 0.5 * (-1 - 0.9) = -0.95
    # episode 2: Q(0, Go2) <- -0.95 + 0.5 * (-1.9 + 0.9^2 * 5 + 0.95) = 0.6
    #            (with gamma^1 instead of gamma^2: 0.825); Q(2, Go3) <- 5 + 0.5 * (10 - 5)
    torch.testing.assert_close(q[0], torch.tensor([0.6, 0.0]))
    torch.testing.assert_close(q[2], torch.tensor([0.0, 7.5]))


def test_hh_learning_model_counts_outcomes_and_primitives_pay_the_gain():
    graph, env = chain()
    learner = HHLearner(graph, 1)
    run(graph, env, learner, 3 + 1 + 3)
    # Root's model: from 0, Go2 (slot 0) ended in state 2 twice; from 2, Go3 (slot 1) ended the
    # episode twice (outcome 4, "terminated"); columns are slot * 5 + outcome
    model = learner.heads["Root"]["model"][0]
    assert model[0, 0 * 5 + 2] == 2 and model[0].sum() == 2
    assert model[2, 1 * 5 + 4] == 2 and model[2].sum() == 2
    # the gain: every step was greedy: (-1 - 1 + 10) * 2 / 6 steps
    assert abs(float(learner.gain[0]) - 16 / 6) < 1e-6
    # H(Right, s) = r(s) - g, and Root backs up H(Root, 0) = H(Go2, 0) + H(Root, 2)
    ctx = graph.context(env.reset())
    learner.evaluate(ctx)
    g = 16 / 6
    right = graph.index["Right"]
    assert abs(float(ctx.values["H"][0, right]) - (-1 - g)) < 1e-5


def test_three_part_choices_add_the_external_completion_and_w_hands_over_to_the_parent():
    graph, env = chain()
    learner = HDRLearner(graph, 1, gamma=0.9)
    root = graph.index["Root"]
    # per-instance tables: Root is instance 0, Go2 and Go3 its children 1 and 2
    heads = learner.heads
    heads["Root"]["C"][0, 2] = torch.tensor([1.0, 2.0])
    heads["Root"]["CE"][0, 2] = torch.tensor([0.5, -4.0])
    heads["Root/Go3"]["C"][0, 0, 0] = 3.0  # Go3 has one abstract state
    heads["Root/Go3"]["CE"][0, 0, 0] = 0.25
    heads["Root/Go3/Right"]["V"][0, 2, 0] = 7.0
    obs = env.reset()
    obs["observation"][:] = 2
    ctx = graph.context(obs)
    learner.evaluate(ctx)
    q = learner.action_values(torch.tensor([0]), ctx)[0]
    # Go2 is terminated at 2 (V 0); Go3: V(Go3, 2) = V(Right) + C(Go3, 2, Right) = 10
    assert float(q[1]) == 10.0 + 2.0 - 4.0
    assert bool(ctx.available[0, root, 1]) and not bool(ctx.available[0, root, 0])
    # W(Go2, 2): Go2 has ended at 2, so the stack above it continues with Root's choice there
    w = ctx.values["W"][0]
    assert float(w[1]) == float(w[0]) == 10.0 + 2.0 - 4.0
    # W(Go3, 2): Go3 still runs at 2 and chooses Right: V + C + CE of Go3
    assert float(w[2]) == 7.0 + 3.0 + 0.25
