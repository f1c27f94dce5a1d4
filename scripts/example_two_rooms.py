"""A complete new hierarchy on a new env, as walked through in docs/your-own-hierarchy.md.

Two rooms joined by a doorway; the agent must reach a goal cell in the far room. The hierarchy
is Root -> {ToDoor, ToGoal} -> {North, South, East, West}.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from hrl_torch.common.devices import constant_on
from hrl_torch.env.batched import BatchedEnv
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.modules.schedules import Linear
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer

# 1. The env: a 5 x 9 grid, wall at column 4 except the doorway at row 2.
ROWS, COLS, WALL_COL, DOOR_ROW = 5, 9, 4, 2
GOAL = (4, 8)
MOVES = torch.tensor([[-1, 0], [1, 0], [0, 1], [0, -1]])  # N, S, E, W


class TwoRoomsEnv(BatchedEnv):
    """Start anywhere in the left room; -1 per step, +10 at the goal (episode ends)."""

    state_keys = ("row", "col")
    observation_sizes = {"cell": ROWS * COLS}

    def __init__(self, seeds, envs_per_learner, max_episode_steps=100):
        super().__init__(seeds, envs_per_learner, n_actions=4, max_episode_steps=max_episode_steps)
        self.row = torch.zeros(self.batch_size, dtype=torch.long)
        self.col = torch.zeros(self.batch_size, dtype=torch.long)

    def _reset_rows(self, mask):
        # always draw for every row (fixed shapes keep populations reproducible)
        row, col = self.rng.integers(ROWS), self.rng.integers(WALL_COL)
        self.row = torch.where(mask, row, self.row)
        self.col = torch.where(mask, col, self.col)

    def _step_all(self, action):
        moves = constant_on(MOVES, action.device)  # (the table on the run's device, copied once)
        row = (self.row + moves[action, 0]).clamp(0, ROWS - 1)
        col = (self.col + moves[action, 1]).clamp(0, COLS - 1)
        blocked = (col == WALL_COL) & (row != DOOR_ROW)
        self.row = torch.where(blocked, self.row, row)
        self.col = torch.where(blocked, self.col, col)
        at_goal = (self.row == GOAL[0]) & (self.col == GOAL[1])
        reward = torch.where(at_goal, 10.0, -1.0)
        return reward, torch.ones_like(reward), at_goal

    def _observe(self):
        return {"cell": self.row * COLS + self.col}


# 2. The subtasks: abstraction, termination and initiation by subclassing.
class GoTo(Subtask):
    """Navigate to one cell; its abstract state is the cell."""

    def __init__(self, name: str, target: tuple[int, int], left_room_only: bool) -> None:
        super().__init__(name, ["North", "South", "East", "West"], n_states=ROWS * COLS)
        self.target = target[0] * COLS + target[1]
        self.left_room_only = left_room_only

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        return obs["cell"]

    def terminated(self, obs: TensorDict) -> torch.Tensor:
        return obs["cell"] == self.target

    def initiable(self, obs: TensorDict) -> torch.Tensor:
        in_left = (obs["cell"] % COLS) < WALL_COL
        return in_left if self.left_room_only else torch.ones_like(in_left)


def two_rooms_hierarchy() -> TaskGraph:
    """Root -> {ToDoor, ToGoal} -> moves; the root sees only which room the agent is in."""
    root = Subtask(
        "Root",
        ["ToDoor", "ToGoal"],
        n_states=2,
        abstract=lambda o: ((o["cell"] % COLS) >= WALL_COL).long(),
    )
    nodes = [
        root,
        GoTo("ToDoor", (DOOR_ROW, WALL_COL), left_room_only=True),
        GoTo("ToGoal", GOAL, left_room_only=False),
        # a move's reward depends on the cell (+10 into the goal), so V(move, s) needs the cell:
        # a single-state primitive (leaf irrelevance) would average the goal bonus into every move
        *(
            Primitive(name, k, n_states=ROWS * COLS, abstract=lambda o: o["cell"])
            for k, name in enumerate(["North", "South", "East", "West"])
        ),
    ]
    return TaskGraph("Root", nodes, n_actions=4)


# 3. Train a population of seeds and evaluate greedily.
def main(steps: int = 20_000, seeds: tuple[int, ...] = tuple(range(5)), progress: bool = True):
    """Train MAXQ-Q on the two rooms; return the trainer's result."""
    torch.set_num_threads(1)
    graph = two_rooms_hierarchy()
    learner = MaxQLearner(graph, len(seeds), alpha=0.5, gamma=1.0, init=-20.0)
    trainer = Trainer(
        TwoRoomsEnv(list(seeds), envs_per_learner=64),
        graph,
        learner,
        EpsilonGreedy(Linear(1.0, 0.05, steps // 2)),
        TrainConfig(steps=steps, eval_every=steps // 5, eval_episodes=50, progress=progress),
        eval_env=TwoRoomsEnv([123] * len(seeds), envs_per_learner=50),
    )
    result = trainer.train()
    print("greedy return per seed:", [round(v, 2) for v in result.final_eval])
    return result


if __name__ == "__main__":
    main()
