"""docs/multiagent-walkthrough.md's blocks, as of hrl-torch 0.1 (f3a1bd5), with the Trainer given ``multiagent=config`` as 0.1 scripts did.

Kept as it was: it must run on 0.2 with DeprecationWarnings (tests/test_compat.py).
"""

import torch

from hrl_torch.multiagent_env import MultiAgentBatchedEnv

LENGTH = 7
LEFT, RIGHT, PICK = 0, 1, 2
BOX_CELLS = (0, LENGTH - 1)  # box A, box B


class TwoRobotsEnv(MultiAgentBatchedEnv):
    state_keys = ("pos", "boxes")  # saved in checkpoints
    observation_sizes = {"boxes": 4}  # shared: bit 0 box A still there, bit 1 box B
    agent_observation_sizes = {"pos": LENGTH}  # each robot's own cell

    def __init__(self, seeds, envs_per_learner, max_episode_steps=30, device="cpu"):
        super().__init__(seeds, envs_per_learner, 2, 3, max_episode_steps, device)  # 2 agents, 3 actions
        self.pos = torch.zeros(self.batch_size, 2, dtype=torch.long, device=self.device)
        self.boxes = torch.full((self.batch_size,), 3, dtype=torch.long, device=self.device)

    def _reset_rows(self, mask):  # draw for every row, keep the masked ones
        start = torch.stack([self.rng.integers(LENGTH - 2) + 1 for _ in range(2)], 1)
        self.pos = torch.where(mask[:, None], start, self.pos)
        self.boxes = self.boxes.masked_fill(mask, 3)

    def _step_all(self, action, acting):
        step = torch.where(action == RIGHT, 1, torch.where(action == LEFT, -1, 0))
        self.pos = (self.pos + step).clamp(0, LENGTH - 1)
        for k, cell in enumerate(BOX_CELLS):
            picked = ((action == PICK) & (self.pos == cell)).any(1)
            self.boxes = torch.where(picked, self.boxes & ~(1 << k), self.boxes)
        reward = torch.full((self.batch_size,), -1.0, device=self.device)  # the team's
        every = torch.ones_like(acting)  # discrete time: both robots act every step
        return reward, torch.ones_like(reward), self.boxes == 0, every

    def _observe(self):
        return {"boxes": self.boxes.clone()}

    def _observe_agents(self):
        return {"pos": self.pos.clone()}

from hrl_torch.graph import Primitive, Subtask, TaskGraph


def fetch(name, bit):
    return Subtask(
        name,
        ["Left", "Right", "Pick"],
        n_states=LENGTH,
        abstract=lambda o: o["pos"],
        initiable=lambda o: (o["boxes"] >> bit) & 1 == 1,
        terminated=lambda o: (o["boxes"] >> bit) & 1 == 0,
    )


def robot_hierarchy():
    root = Subtask(
        "Root", ["FetchA", "FetchB"], n_states=LENGTH * 4, abstract=lambda o: o["pos"] * 4 + o["boxes"]
    )
    moves = [Primitive("Left", LEFT), Primitive("Right", RIGHT), Primitive("Pick", PICK)]
    return TaskGraph("Root", [root, fetch("FetchA", 0), fetch("FetchB", 1), *moves], n_actions=3)

from pettingzoo.test import api_test, parallel_api_test

from hrl_torch.envcheck import check_env
from hrl_torch.pettingzoo_env import MultiAgentAECEnv, MultiAgentParallelEnv

check_env(TwoRobotsEnv([0], 2), make_env=TwoRobotsEnv, torchrl=True)
api_test(MultiAgentAECEnv(TwoRobotsEnv, seed=0), num_cycles=100)
parallel_api_test(MultiAgentParallelEnv(TwoRobotsEnv, seed=0), num_cycles=100)

from hrl_torch.exploration import EpsilonGreedy, Linear
from hrl_torch.learners import MaxQLearner
from hrl_torch.multiagent import Cooperation, MultiAgentConfig, cooperative_graph
from hrl_torch.trainer import TrainConfig, Trainer

torch.set_num_threads(1)
seeds, steps = [0, 1, 2], 12_000
cooperation = Cooperation((("Root",),))
config = MultiAgentConfig(cooperation)
graph = cooperative_graph(robot_hierarchy(), cooperation, 2)
learner = MaxQLearner(graph, config.table_sets(len(seeds), 2), alpha=0.3, gamma=1.0, init=-10.0)
trainer = Trainer(
    TwoRobotsEnv(seeds, 16),
    graph,
    learner,
    EpsilonGreedy(Linear(1.0, 0.05, steps // 2)),
    TrainConfig(steps=steps, eval_every=2_000, eval_episodes=50),
    eval_env=TwoRobotsEnv([123] * len(seeds), 50),
    multiagent=config,  # 0.1's way: the Trainer built the agents itself
)
result = trainer.train()
print("greedy return per seed:", [round(v, 2) for v in result.final_eval])
