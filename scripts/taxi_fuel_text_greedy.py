"""What a trained taxi-fuel learner's greedy policy does over its evaluation run.

Loads a run folder's ``checkpoint.pt`` and runs the greedy evaluation's protocol (the eval
seed, ``EVAL_ROWS`` rows, ``EVAL_HORIZON`` steps from a reset) once, counting per seed the
deliveries, the episodes that ran dry, the illegal Pickups and Dropoffs, the Fillups (at F or
not), and the rows whose last 100 steps ended no episode (a greedy loop, which nothing breaks
without a time limit).

    python scripts/taxi_fuel_text_greedy.py RUN_DIR [RUN_DIR ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from agents.taxi_fuel_text import DOMAIN, EVAL_HORIZON, EVAL_ROWS
from envs.taxi_fuel import FILLUP
from hrl_torch.runs.experiment import RunOptions, build_trainer

TAIL = 100  # steps with no episode end that mark a loop


@torch.no_grad()
def greedy_counts(run_dir: Path) -> dict[str, list[float]]:
    """Per seed: reward per step, deliveries, dry runs, illegal actions, Fillups, looping rows."""
    hparams = json.loads((run_dir / "hparams.json").read_text())
    seeds, steps = hparams["options.seeds"], hparams["options.steps"]
    opts = RunOptions(seeds=seeds, steps=steps, progress=False, tensorboard=False)
    trainer = build_trainer(DOMAIN, hparams["algo"], opts)
    trainer.load(run_dir / "checkpoint.pt")
    env = trainer.eval_env
    env.rng.load_state_dict({"counter": 0})
    agent = trainer.evaluation_agent(env, "eval-explore")
    action = agent.start(env.reset())
    sums = torch.zeros(5, env.batch_size)  # reward, deliveries, dry, illegal, Fillups
    last_end = torch.zeros(env.batch_size)
    for k in range(EVAL_HORIZON):
        fillup = (action == FILLUP).float()
        td = env.step(action)
        reward = td["reward"]
        ended = td["terminated"]
        sums += torch.stack([reward, (reward == 20).float(), (reward == -20).float(),
                             (reward == -10).float(), fillup])  # fmt: skip
        last_end = torch.where(ended, float(k), last_end)
        action = agent.step(td)
    looping = (last_end < EVAL_HORIZON - TAIL).float()
    per_seed = torch.cat([sums, looping[None]]).view(6, len(seeds), EVAL_ROWS).sum(-1)
    names = ("reward_per_step", "deliveries", "dry", "illegal", "fillups", "looping_rows")
    out = {n: per_seed[i].tolist() for i, n in enumerate(names)}
    out["reward_per_step"] = [r / (EVAL_ROWS * EVAL_HORIZON) for r in out["reward_per_step"]]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(1)
    for run_dir in args.runs:
        counts = greedy_counts(run_dir)
        print(run_dir.name)
        for name, values in counts.items():
            print(f"  {name}: " + ", ".join(f"{v:.3f}" if v % 1 else f"{v:.0f}" for v in values))


if __name__ == "__main__":
    main()
