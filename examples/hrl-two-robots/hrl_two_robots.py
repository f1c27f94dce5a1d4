"""A multi-agent domain plugin for hrl-torch, in one file: two robots fetch two boxes.

A corridor of ``LENGTH`` cells has box A in cell 0 and box B in the last cell. Two robots start
in random inner cells; each step every robot moves Left or Right or tries to Pick a box in its
cell. The episode ends when both boxes are picked; the team pays -1 per step. The best plan
splits the boxes (one robot each); two robots that chase one box waste the steps the loser walks
back. The walkthrough in ``docs/multiagent-walkthrough.md`` builds this file step by step.

Each robot runs a copy of Root -> {FetchA, FetchB} -> {Left, Right, Pick}; ``Root`` is the
cooperative subtask of Cooperative HRL (its completions also see the other robot's task).
"""

from __future__ import annotations

import torch

from hrl_torch.common.config import Make
from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import linear_epsilon
from hrl_torch.multiagent.cooperative import Cooperation, MultiAgentConfig, cooperative_graph
from hrl_torch.runs.domain import DomainSpec, algo_family
from hrl_torch.training.config import TrainConfig

LENGTH = 7
LEFT, RIGHT, PICK = 0, 1, 2
BOX_CELLS = (0, LENGTH - 1)  # box A, box B


class TwoRobotsEnv(MultiAgentBatchedEnv):
    """``pos [B, 2]`` of the robots, ``boxes [B]`` still in place (bit 0: A, bit 1: B)."""

    state_keys = ("pos", "boxes")
    observation_sizes = {"boxes": 4}  # shared fields
    agent_observation_sizes = {"pos": LENGTH}  # each robot's own fields

    def __init__(self, seeds, envs_per_learner, max_episode_steps=30, device="cpu"):
        super().__init__(seeds, envs_per_learner, 2, 3, max_episode_steps, device)
        self.pos = torch.zeros(self.batch_size, 2, dtype=torch.long, device=self.device)
        self.boxes = torch.full((self.batch_size,), 3, dtype=torch.long, device=self.device)

    def _reset_rows(self, mask):
        start = torch.stack([self.rng.integers(LENGTH - 2) + 1 for _ in range(2)], 1)
        self.pos = torch.where(mask[:, None], start, self.pos)  # drawn for every row
        self.boxes = self.boxes.masked_fill(mask, 3)

    def _step_all(self, action, acting):
        step = torch.where(action == RIGHT, 1, torch.where(action == LEFT, -1, 0))
        self.pos = (self.pos + step).clamp(0, LENGTH - 1)
        for k, cell in enumerate(BOX_CELLS):  # a robot picking at a box's cell takes it
            picked = ((action == PICK) & (self.pos == cell)).any(1)
            self.boxes = torch.where(picked, self.boxes & ~(1 << k), self.boxes)
        reward = torch.full((self.batch_size,), -1.0, device=self.device)  # the team's
        every = torch.ones_like(acting)  # discrete time: both robots act every step
        return reward, torch.ones_like(reward), self.boxes == 0, every

    def _observe(self):
        return {"boxes": self.boxes.clone()}

    def _observe_agents(self):
        return {"pos": self.pos.clone()}


def _fetch(name: str, bit: int) -> Subtask:
    """Go to a box and pick it; ends when the box is gone (picked by either robot)."""
    return Subtask(
        name,
        ["Left", "Right", "Pick"],
        n_states=LENGTH,
        abstract=lambda o: o["pos"],
        initiable=lambda o: (o["boxes"] >> bit) & 1 == 1,
        terminated=lambda o: (o["boxes"] >> bit) & 1 == 0,
    )


def robot_hierarchy() -> TaskGraph:
    """One robot's graph: Root sees its cell and the boxes left (28 states)."""
    root = Subtask(
        "Root",
        ["FetchA", "FetchB"],
        n_states=LENGTH * 4,
        abstract=lambda o: o["pos"] * 4 + o["boxes"],
    )
    moves = [Primitive("Left", LEFT), Primitive("Right", RIGHT), Primitive("Pick", PICK)]
    return TaskGraph("Root", [root, _fetch("FetchA", 0), _fetch("FetchB", 1), *moves], 3)


COOPERATION = Cooperation((("Root",),))  # the root is the cooperative subtask


def make_env(seeds, envs_per_learner, backend="torch"):
    """The domain's env factory (torch backend only)."""
    return TwoRobotsEnv(seeds, envs_per_learner)


spec = algo_family(
    learner=Make(MaxQLearner, alpha=0.3, gamma=1.0, init=-10.0),
    exploration=linear_epsilon(1.0, 0.05, 0.5),  # 1 -> 0.05 over the first half of the budget
    train=TrainConfig(steps=12_000, eval_every=2_000, eval_episodes=50, threshold=-5.0),
    envs_per_learner=16,
)
DOMAIN = DomainSpec(
    name="two-robots",
    make_env=make_env,
    description="two robots fetch two boxes at the ends of a corridor (an hrl-torch plugin)",
    algos={
        "cooperative": spec(
            lambda: cooperative_graph(robot_hierarchy(), COOPERATION, 2),
            "Cooperative HRL: the root's completions also see the other robot's task",
            MultiAgentConfig(COOPERATION),
        ),
        "selfish": spec(robot_hierarchy, "selfish multi-agent HRL: each robot learns alone"),
    },
)
