"""Ship steering: one low-level subtask alone (Figure 5.5), as ``hybrid`` pretrains it.

Prints the successes per block of 1000 training episodes and, on the mean action from uniform
starts, the success per band of start heading error (``ship_low_level_check``).

    python scripts/ship_pretrain.py --subtask 0 --seeds 1 --set pretrain_episodes=15000
"""

from __future__ import annotations

import argparse
from dataclasses import fields

import numpy as np
import torch

from agents.ship import SUBTASK_NAMES
from agents.ship_text import TEXT, pretrain_subtask, subtask_coder, with_overrides
from scripts.ship_low_level_check import learned, report, run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--subtask", type=int, default=0, choices=[0, 1])
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--starts", type=int, default=4000)
    parser.add_argument("--set", nargs="*", default=[], help="TextParams, e.g. pg_beta=0.95")
    a = parser.parse_args()
    torch.set_num_threads(1)
    kinds = {f.name: type(getattr(TEXT, f.name)) for f in fields(TEXT)}
    changes = {}
    for item in a.set:
        key, value = item.split("=")
        if key not in kinds:
            parser.error(f"--set {key}: not a TextParams field")
        changes[key] = value.lower() == "true" if kinds[key] is bool else kinds[key](value)
    params = with_overrides(**changes)
    name = SUBTASK_NAMES[a.subtask]
    learner, stats = pretrain_subtask(a.subtask, list(range(a.seeds)), params)
    blocks = min(stats["episodes"]) // 1000
    print(f"{name} {changes}: {stats['episodes']} episodes, {stats['seconds']:.0f} s")
    for p, curve in enumerate(stats["success_per_block"]):
        print(f"  seed {p} successes per block: {np.round(curve[:blocks], 3).tolist()}")
        policy = learned(learner.group_view(name, p), subtask_coder(a.subtask, params))
        report(f"seed {p}, mean action", *run(a.subtask, policy, a.starts, seed=p))


if __name__ == "__main__":
    main()
