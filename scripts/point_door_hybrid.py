"""The hybrid on the held-out point-door task: share of the door rule's steps per seed.

    .venv/bin/python scripts/point_door_hybrid.py --seeds 5 --steps 100000 [--rooms] \
        [--set alpha=0.003 ...]

``--set`` overrides a ``PGConfig`` field (the defaults otherwise; ``online=True`` is the rule
before issue 33). ``--rooms``: the hierarchy with ``initiable`` rooms (``point_door_hierarchy``).
The state-baseline rows of docs/defaults.md were first run through ``agents/ship_text.py``'s
``LowLevelPG`` with ``online=False``; the framework's default gives the same numbers.

Prints, at each log, the PG groups' scalars (``hrl_torch.learners.pg_stats``) averaged over
seeds, and at the end, per seed, the greedy evaluation's mean steps, its share of the
reference (rule steps / steps) and how many greedy episodes hit the step limit.
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from agents.point_door import make_hybrid, point_door_hierarchy, relative_tile_coder
from envs.point_door import PointDoorEnv
from hrl_torch.learners.pg import PGConfig
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer
from scripts.point_door_reference import EVAL_EPISODES, EVAL_SEED, rule_episodes

SHOW = ("return_per_invocation", "policy_mean", "policy_spread", "gradient_norm", "success")


class PrintLogger:
    """Keeps the training scalars; prints the PG groups' seed means."""

    def __init__(self) -> None:
        self.rows = []

    def __bool__(self) -> bool:
        return True

    def log(self, step, scalars) -> None:
        keep = {k: v for k, v in scalars.items() if k.split("/")[-1] in SHOW}
        mean = {k: float(torch.tensor(v, dtype=torch.float64).nanmean()) for k, v in keep.items()}
        self.rows.append((step, mean))
        print(step, " ".join(f"{k.split('/', 1)[1]}={v:.3g}" for k, v in sorted(mean.items())))

    def log_episodes(self, *args, **kwargs) -> None:
        pass


def parse_set(items):
    out = {}
    for item in items:
        key, value = item.split("=")
        out[key] = {"True": True, "False": False}.get(value, None)
        if out[key] is None:
            out[key] = float(value) if "." in value or "e" in value else int(value)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=40_000)
    ap.add_argument("--envs", type=int, default=16)
    ap.add_argument("--epsilon", type=float, default=0.1)
    ap.add_argument("--res", type=int, default=10)
    ap.add_argument("--tilings", type=int, default=8)
    ap.add_argument("--set", nargs="*", default=[])
    ap.add_argument("--rooms", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    seeds = list(range(args.seeds))
    graph = point_door_hierarchy(args.rooms)
    config = PGConfig(**parse_set(args.set))
    learner = make_hybrid(graph, len(seeds), config, relative_tile_coder(args.res, args.tilings))
    logger = PrintLogger()
    trainer = Trainer(
        PointDoorEnv(seeds, args.envs),
        graph,
        learner,
        EpsilonGreedy(args.epsilon),
        TrainConfig(
            steps=args.steps,
            eval_every=0,
            eval_episodes=EVAL_EPISODES,
            eval_max_steps=200,
            log_every=args.steps // 8,
            progress=False,
        ),
        eval_env=PointDoorEnv([EVAL_SEED] * len(seeds), EVAL_EPISODES),
        logger=logger,
    )
    t0 = time.time()
    trainer.train()
    rec = trainer.evaluate_episodes()
    ref = rule_episodes()[0].double().mean().item()
    length = rec["length"].double().view(len(seeds), -1)
    trunc = rec["truncated"].view(len(seeds), -1).sum(1)
    share = ref / length.mean(1)
    tiles = f"{args.res}x{args.tilings}"
    print(f"rooms {args.rooms} config {config} envs {args.envs} eps {args.epsilon} tiles {tiles}")
    print(f"reference {ref:.2f} steps; wall {time.time() - t0:.0f} s")
    for s in seeds:
        print(
            f"seed {s}: mean steps {length[s].mean():.2f} share {share[s]:.3f} "
            f"truncated {int(trunc[s])}/{EVAL_EPISODES}"
        )
    met = int((share >= 0.95).sum())
    print(json.dumps({"share": share.tolist(), "truncated": trunc.tolist(), "seeds_95": met}))


if __name__ == "__main__":
    main()
