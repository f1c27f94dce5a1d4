"""The executor's greedy flags: a choice counts as greedy only if every ancestor's was."""

import torch

from hrl_torch.execution.executor import HierarchicalExecutor
from hrl_torch.execution.transitions import LEVEL, PRIMITIVE
from tests.learners.test_q_lambda_and_hh_exact import chain


class ExploreAtRoot:
    """First available child; the root's choices are flagged exploratory, the others greedy."""

    def new_step(self):
        pass

    def select(self, inst, ctx, available, step, push):
        return available.float().argmax(-1), inst != 0


def test_a_greedy_child_of_an_exploratory_choice_is_not_greedy():
    graph, env = chain()
    ex = HierarchicalExecutor(graph, 1, 1)
    ctx = graph.context(env.reset())
    ex.act(ctx, ExploreAtRoot(), 0)
    # Root -> Go2 -> Right: the root chose exploring, so no level below it counts as greedy
    assert torch.equal(ex.stack.greedy[0], torch.tensor([False, False, False]))
    flags = []
    for _ in range(3):  # Go2 runs 0 -> 1 -> 2, then Go3 2 -> 3
        td = env.step(ex._action)
        ctx = graph.context(td)
        batch = ex.observe(td, ctx)
        level, prim = batch[LEVEL], batch[PRIMITIVE]
        flags.append(bool(prim["greedy"][0]))
        done = level["valid"][0]
        if bool(done[1]):  # Go's child Right ended: own choice greedy, its ancestor's not
            assert bool(level["own_greedy"][0, 1]) and not bool(level["greedy"][0, 1])
        if bool(done[0]):  # the root's own choice was exploratory
            assert not bool(level["own_greedy"][0, 0]) and not bool(level["greedy"][0, 0])
        ex.act(ctx, ExploreAtRoot(), 0)
    assert flags == [False, False, False]  # every primitive step lies under the root's choice


def test_starting_again_after_an_episode_end_puts_every_row_at_the_root():
    # a row whose episode just ended waits for its reset (done); emptying the stacks for a new
    # start must clear that mark, or the row would never act again
    from hrl_torch.common.rng import BatchRNG
    from hrl_torch.learners import SMDPQLearner
    from hrl_torch.modules.exploration import Greedy
    from hrl_torch.training.agent import HierarchicalAgent

    graph, env = chain()
    agent = HierarchicalAgent(graph, SMDPQLearner(graph, 1), Greedy(), BatchRNG([0], 1, "x"), 1)
    action = agent.start(env.reset())
    for _ in range(3):  # the whole episode: 0 -> 1 -> 2 -> 3
        action = agent.step(env.step(action))
    assert bool(agent.executor.stack.done.all()) and int(agent.executor.stack.top[0]) == -1
    agent.start(env.reset())
    assert not bool(agent.executor.stack.done.any())
    assert int(agent.executor.stack.top[0]) == 2  # Root -> Go2 -> Right
