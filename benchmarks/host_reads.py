"""Host reads and data-dependent ops per training step, every registered domain x algorithm.

``hrl_torch.common.sync_count.HostSyncCounter`` around ``trainer.train_step()`` on the CPU, with the
static paths a GPU takes (``broadcast.STATIC_ROUNDS``, ``devices.STATIC_SHAPES``): 2 seeds x
2 envs, 5 steps of warm-up, then the mean over 70 steps (one block of random draws,
``BatchRNG.AHEAD`` = 64, included). Deterministic. Prints one markdown table row per
configuration: ``| domain | algorithm | per step (kinds) |``.

    PYTHONPATH=. python benchmarks/host_reads.py [DOMAIN/ALGO ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import agents  # noqa: E402,F401  (registers the domains)
import hrl_torch.common.devices  # noqa: E402
import hrl_torch.multiagent.broadcast  # noqa: E402
from hrl_torch.common.sync_count import count_train_step  # noqa: E402
from hrl_torch.runs import registry  # noqa: E402
from hrl_torch.runs.experiment import RunOptions, build_trainer  # noqa: E402


def row(domain: str, algo: str, steps: int = 70) -> str:
    """The table row of one configuration."""
    opts = RunOptions(
        seeds=[0, 1],
        envs_per_learner=2,
        progress=False,
        tensorboard=False,
        eval_episodes=0,
        check_env=False,
    )
    trainer = build_trainer(registry.get(domain), algo, opts)
    count_train_step(trainer, 5)
    c = count_train_step(trainer, steps)
    kinds = ", ".join(f"{k} {v / steps:.2f}" for k, v in c.counts.most_common())
    return f"| {domain} | {algo} | {c.total / steps:.2f} ({kinds or '-'}) |"


def main(argv: list[str]) -> int:
    torch.set_num_threads(1)
    hrl_torch.multiagent.broadcast.STATIC_ROUNDS = True
    hrl_torch.common.devices.STATIC_SHAPES = True
    pairs = [a.split("/") for a in argv] or [
        (d, a) for d in registry.names() for a in registry.get(d).algos
    ]
    for domain, algo in pairs:
        print(row(domain, algo), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
