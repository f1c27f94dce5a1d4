"""The README's training script, as of hrl-torch 0.1 (f3a1bd5).

Kept as it was: it must run on 0.2 with DeprecationWarnings (tests/test_compat.py).
"""

import torch
from agents.taxi import taxi_hierarchy
from envs.taxi import TaxiEnv
from hrl_torch.exploration import EpsilonGreedy, Linear
from hrl_torch.learners import MaxQLearner
from hrl_torch.trainer import Trainer, TrainConfig

torch.set_num_threads(1)  # small ops: one thread is much faster
seeds = list(range(10))
graph = taxi_hierarchy()  # Root -> Get/Put -> Navigate(t) -> moves
learner = MaxQLearner(graph, n_learners=len(seeds), alpha=0.5, gamma=1.0)
trainer = Trainer(
    TaxiEnv(seeds, envs_per_learner=256),
    graph,
    learner,
    EpsilonGreedy(Linear(1.0, 0.05, 20_000)),
    TrainConfig(steps=60_000, eval_every=5_000, threshold=7.5),
    eval_env=TaxiEnv([7] * len(seeds), envs_per_learner=100),
)
result = trainer.train()
print(result.final_eval, result.steps_to_threshold)
trainer.save("taxi.pt")
