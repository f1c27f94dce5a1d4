"""Greedy episodes that loop until the step limit are named in the evaluation record.

A corridor whose greedy policy steps Right at cell 0 and Left at cell 1 never reaches the goal:
every evaluation episode hits the step limit, and the record names the 2-step cycle it looped
in (``hrl_torch.training.loops``), in the evaluator, the CSV, the summary and the progress line.
"""

import csv

import torch

from hrl_torch.env.batched import BatchedEnv
from hrl_torch.hierarchy.graph import Primitive, Subtask, TaskGraph
from hrl_torch.learners import SMDPQLearner
from hrl_torch.modules.exploration import Greedy
from hrl_torch.training.loops import cycle, limit_note
from hrl_torch.training.runlog import RunLogger, read_episodes
from hrl_torch.training.trainer import TrainConfig, Trainer

CELLS = 5


class Corridor(BatchedEnv):
    state_keys = ("cell",)
    observation_sizes = {"cell": CELLS}

    def __init__(self, seeds, envs_per_learner, max_episode_steps=12):
        super().__init__(seeds, envs_per_learner, 2, max_episode_steps)
        self.cell = torch.zeros(self.batch_size, dtype=torch.long)

    def _reset_rows(self, mask):
        self.cell = self.cell.masked_fill(mask, 0)

    def _step_all(self, action):
        self.cell = (self.cell + torch.where(action == 1, 1, -1)).clamp(0, CELLS - 1)
        done = self.cell == CELLS - 1
        return torch.where(done, 10.0, -1.0), torch.ones(self.batch_size), done

    def _observe(self):
        return {"cell": self.cell.clone()}


def _looping_trainer():
    root = Subtask("Root", ["Left", "Right"], n_states=CELLS, abstract=lambda o: o["cell"])
    graph = TaskGraph("Root", [root, Primitive("Left", 0), Primitive("Right", 1)], n_actions=2)
    learner = SMDPQLearner(graph, 2)
    q = torch.zeros(2, CELLS, 2)
    q[:, :, 1] = 1.0  # Right everywhere ...
    q[1, 1] = torch.tensor([2.0, 0.0])  # ... except learner 1 at cell 1: Left (0 <-> 1 loop)
    learner.load_state_dict({**learner.state_dict(), "heads.Root.Q": q})
    config = TrainConfig(steps=1, eval_every=0, eval_episodes=3, progress=False)
    return Trainer(
        Corridor([0, 1], 2), graph, learner, Greedy(), config, eval_env=Corridor([5, 5], 3)
    )


def test_a_looping_greedy_policy_is_named_with_its_cycle(tmp_path):
    trainer = _looping_trainer()
    trainer.evaluate()
    records, loops = trainer.last_eval_records, trainer.evaluator.last_loops
    assert records["truncated"].tolist() == [False] * 3 + [True] * 3
    assert records["length"].tolist() == [4.0] * 3 + [12.0] * 3
    assert loops[:3] == [""] * 3
    assert loops[3:] == ["2-step cycle: cell=1 -> cell=0"] * 3
    summary = trainer.evaluator.summary(1)["final_eval_step_limit"]
    assert summary == [{"episode": k, "loop": "2-step cycle: cell=1 -> cell=0"} for k in range(3)]
    assert trainer.evaluator.summary(0) == {"final_eval_step_limit": []}
    note = limit_note(records, loops)
    assert note == (
        "; 3 greedy episode(s) hit the step limit (seed 1 episode 0: 2-step cycle: cell=1 -> "
        "cell=0; 2 more in eval_episodes.csv)"
    )
    logger = RunLogger(tmp_path, [0, 1], {}, tensorboard=False)
    logger.log_episodes(7, records, trainer.graph.names, loops=loops)
    rows = read_episodes(tmp_path)
    assert [r["loop"] for r in rows if r["truncated"]] == loops[3:]
    assert all(r["loop"] == "" for r in rows if not r["truncated"])


def test_a_file_begun_before_the_loop_column_keeps_its_columns(tmp_path):
    trainer = _looping_trainer()
    trainer.evaluate()
    old = "step,seed,episode,return,length,success,truncated,start,decisions,partial\n"
    (tmp_path / "eval_episodes.csv").write_text(old)
    logger = RunLogger(tmp_path, [0, 1], {}, tensorboard=False)
    logger.log_episodes(7, trainer.last_eval_records, trainer.graph.names, loops=["x"] * 6)
    with open(tmp_path / "eval_episodes.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert all(len(r) == 10 for r in rows) and len(rows) == 7


def test_cycle_finds_the_shortest_period():
    seq = torch.tensor([[1], [2], [3], [1], [2], [3], [1], [2], [3]])
    assert cycle(seq) == 3
    assert cycle(torch.tensor([[4]] * 6)) == 1
    assert cycle(torch.tensor([[1], [2], [3], [4]])) == 0
