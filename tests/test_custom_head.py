"""A user's own policy head, written outside hrl_torch, plugged into a PG node, and learning."""

import math

import torch

from hrl_torch.learners.pg import HPGRLLearner, PGConfig
from hrl_torch.modules.exploration import Greedy, masked_argmax
from hrl_torch.modules.heads import PolicyChoice, PolicyHead, PolicyInput
from hrl_torch.modules.policies import sample_categorical
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer
from tests.helpers import TableEnv
from tests.learners.test_hpgrl import NEXT, REWARD, STARTS, TERMINAL, N, hierarchy


class CoolingSoftmaxHead(PolicyHead):
    """Softmax over ``theta[s, :] / T(step)`` with a temperature cooling from 2 to 0.5."""

    def __init__(self, name: str, n_states: int, n_children: int) -> None:
        super().__init__(name, n_states, n_children)
        self.width = n_children

    def temperature(self, step: int) -> float:
        return max(0.5, 2.0 - step / 2_000)

    def act(self, theta: torch.Tensor, inp: PolicyInput, greedy: bool) -> PolicyChoice:
        ok = inp.available[:, : self.n_cols]
        cols = torch.arange(self.n_cols)
        index = inp.base[:, None] + inp.state[:, None] * self.n_cols + cols
        index = torch.where(ok, index, theta.numel() - 1)
        t = self.temperature(inp.step)
        logits = (theta[index] / t).masked_fill(~ok, -math.inf)
        probs = torch.softmax(logits, -1)
        best = masked_argmax(logits, ok)
        pick = best if greedy else sample_categorical(probs, inp.u[:, 0])
        # d log mu(a|s) / d theta[s, b] = (onehot(a) - mu(b|s)) / T
        score = (torch.nn.functional.one_hot(pick, self.n_cols) - probs) / t
        return PolicyChoice(pick, pick == best, None, index, torch.where(ok, score, 0.0))


def greedy_return(trainer: Trainer) -> float:
    return float(trainer.evaluate()[0].mean())


def test_a_custom_head_plugs_into_a_node_names_its_tensors_and_learns():
    graph = hierarchy()  # Root chooses A or B; A and B move right or left in a corridor
    heads = {k: CoolingSoftmaxHead(k, N, 2) for k in ("Root", "A", "B")}
    learner = HPGRLLearner(graph, 2, PGConfig(alpha=0.05, trace_len=400), heads=heads)
    assert {k for k in learner.state_dict() if k.startswith("heads.")} == {
        "heads.Root.theta",
        "heads.A.theta",
        "heads.B.theta",
    }
    terminal = torch.arange(N) == TERMINAL
    env = TableEnv(NEXT, REWARD, terminal, STARTS, [0, 1], 16, max_episode_steps=50)
    eval_env = TableEnv(NEXT, REWARD, terminal, STARTS, [7, 7], 40, max_episode_steps=30)
    config = TrainConfig(steps=3_000, eval_every=0, progress=False)
    trainer = Trainer(env, graph, learner, Greedy(), config, eval_env=eval_env)
    untrained = greedy_return(trainer)  # measured: 0.61
    trainer.train()
    trained = greedy_return(trainer)
    # the best policy reaches state 0 and stays there with "left" (+0.5 a step): at most 15 in
    # the 30 steps of an evaluation episode; measured after 3,000 steps: 13.4
    assert untrained < 2.0
    assert trained > 10.0, (untrained, trained)
