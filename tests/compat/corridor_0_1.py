"""A domain file written for hrl-torch 0.1 (examples/hrl-corridor at 1eac21f^), kept as it was.

Only two things differ from the file of that day: ``AlgoSpec`` is called positionally, as some
users did, and the spec is named ``corridor-0-1``. It must keep running on 0.2 with
DeprecationWarnings (tests/test_compat.py).

Fetch at one end of a corridor, deliver at the other.

The corridor has ``LENGTH`` cells; an episode starts in a random cell without the item. Moving
into cell 0 picks the item up; reaching the last cell with it delivers it (+10, the episode
ends); every other step costs -1. The hierarchy: Root -> {Fetch, Deliver} -> {Left, Right}.
"""

from __future__ import annotations

import torch

from hrl_torch.env import BatchedEnv
from hrl_torch.experiment import AlgoSpec, DomainSpec
from hrl_torch.exploration import EpsilonGreedy, Linear
from hrl_torch.graph import Primitive, Subtask, TaskGraph
from hrl_torch.learners import MaxQLearner, SMDPQLearner
from hrl_torch.trainer import TrainConfig

LENGTH = 8
LEFT, RIGHT = 0, 1


class CorridorEnv(BatchedEnv):
    """``pos`` in ``[0, LENGTH)``, ``carrying`` 0/1; -1 per step, +10 on delivery."""

    state_keys = ("pos", "carrying")
    observation_sizes = {"pos": LENGTH, "carrying": 2, "state": 2 * LENGTH}

    def __init__(self, seeds, envs_per_learner, max_episode_steps=60, device="cpu"):
        super().__init__(seeds, envs_per_learner, 2, max_episode_steps, device)
        self.pos = torch.zeros(self.batch_size, dtype=torch.long, device=self.device)
        self.carrying = torch.zeros_like(self.pos)

    def _reset_rows(self, mask):
        start = self.rng.integers(LENGTH - 1) + 1  # drawn for every row
        self.pos = torch.where(mask, start, self.pos)
        self.carrying = self.carrying.masked_fill(mask, 0)

    def _step_all(self, action):
        self.pos = (self.pos + torch.where(action == RIGHT, 1, -1)).clamp(0, LENGTH - 1)
        self.carrying = self.carrying | (self.pos == 0).long()
        delivered = (self.carrying == 1) & (self.pos == LENGTH - 1)
        reward = torch.where(delivered, 10.0, -1.0)
        return reward, torch.ones_like(reward), delivered

    def _observe(self):
        state = self.carrying * LENGTH + self.pos
        return {"pos": self.pos, "carrying": self.carrying, "state": state}


def moves() -> list[Primitive]:
    """Left and Right, whose values see the full state.

    Right's reward depends on the state (the delivery): one abstract state for all would break
    leaf irrelevance, and Fetch would prefer Right everywhere.
    """
    return [
        Primitive(name, action, n_states=2 * LENGTH, abstract=lambda o: o["state"])
        for name, action in (("Left", LEFT), ("Right", RIGHT))
    ]


def corridor_hierarchy() -> TaskGraph:
    """Root sees whether the item is carried; Fetch and Deliver see the position."""
    root = Subtask("Root", ["Fetch", "Deliver"], n_states=2, abstract=lambda o: o["carrying"])
    fetch = Subtask(
        "Fetch",
        ["Left", "Right"],
        n_states=LENGTH,
        abstract=lambda o: o["pos"],
        terminated=lambda o: o["carrying"] == 1,
    )
    deliver = Subtask(
        "Deliver",
        ["Left", "Right"],
        n_states=LENGTH,
        abstract=lambda o: o["pos"],
        initiable=lambda o: o["carrying"] == 1,
        terminated=lambda o: o["pos"] == LENGTH - 1,
    )
    return TaskGraph("Root", [root, fetch, deliver, *moves()], n_actions=2)


def flat_graph() -> TaskGraph:
    """Flat Q-learning: Root chooses moves in every (position, carrying) state."""
    root = Subtask("Root", ["Left", "Right"], n_states=2 * LENGTH, abstract=lambda o: o["state"])
    return TaskGraph("Root", [root, *moves()], n_actions=2)


def make_env(seeds, envs_per_learner, backend="torch"):
    """The domain's env factory (torch backend only)."""
    return CorridorEnv(seeds, envs_per_learner)


def _epsilon(config: TrainConfig) -> EpsilonGreedy:
    return EpsilonGreedy(Linear(1.0, 0.05, config.steps // 2))


def algo(make_graph, learner_class, description: str) -> AlgoSpec:
    """One algorithm: its graph and learner; the budget and exploration are shared."""
    return AlgoSpec(
        make_graph,
        lambda g, n: learner_class(g, n, alpha=0.5, gamma=1.0),
        _epsilon,
        # the optimal greedy return over the evaluation episodes is about -0.5
        TrainConfig(steps=3_000, eval_every=500, eval_episodes=20, threshold=-1),
        8,
        description=description,
    )


DOMAIN = DomainSpec(
    name="corridor-0-1",
    make_env=make_env,
    description="fetch at the left end, deliver at the right end (an hrl-torch plugin)",
    algos={
        "maxq-q": algo(
            corridor_hierarchy,
            MaxQLearner,
            "MAXQ-Q over Root -> {Fetch, Deliver} -> {Left, Right}",
        ),
        "q": algo(flat_graph, SMDPQLearner, "flat Q-learning over (position, carrying)"),
    },
)
