"""Why a plain MAXQ-Q relapses into wall-bumping loops on taxi, and the fix.

Trains MAXQ-Q (10 seeds, alpha 0.1, epsilon 1.0 -> 0.01) twice: with zero initial completion
values (optimistic: every true value is negative) and with pessimistic ones (-20). Prints the
greedy evaluation return at every evaluation and, at the end, how many of the 100 evaluation
episodes per seed end in a greedy loop (cut by the 200-step limit). See docs/design.md,
"Initial values and greedy loops".
"""

from __future__ import annotations

import argparse

import torch

from agents.taxi import PESSIMISTIC_INIT, taxi_hierarchy
from envs.taxi import TaxiEnv
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.modules.schedules import Linear
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer


def run(init: float, seeds: list[int], steps: int, envs: int) -> Trainer:
    graph = taxi_hierarchy()
    learner = MaxQLearner(graph, len(seeds), alpha=0.1, gamma=1.0, init=init)
    trainer = Trainer(
        TaxiEnv(seeds, envs),
        graph,
        learner,
        EpsilonGreedy(Linear(1.0, 0.01, steps // 4)),
        TrainConfig(steps=steps, eval_every=steps // 15, threshold=7.5, progress=False),
        eval_env=TaxiEnv([1_000_003] * len(seeds), 100),
    )
    trainer.train()
    return trainer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--steps", type=int, default=60_000)
    parser.add_argument("--envs", type=int, default=16)
    args = parser.parse_args()
    torch.set_num_threads(1)
    seeds = list(range(args.seeds))
    for name, init in (("zero (optimistic)", 0.0), ("pessimistic", PESSIMISTIC_INIT)):
        trainer = run(init, seeds, args.steps, args.envs)
        print(f"\n## initial completion values: {name} ({init})")
        print("env steps | greedy eval return per seed")
        for step, values in trainer.curve:
            print(f"{step:>9} | {' '.join(f'{v:7.1f}' for v in values)}")
        _, success = trainer.evaluate()
        loops = ((1 - success) * 100).round().int().tolist()
        print(f"episodes cut by the time limit at the end (of 100), per seed: {loops}")


if __name__ == "__main__":
    main()
