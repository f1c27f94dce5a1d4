"""One hash per registered configuration: its settings and the tables a short run learns.

    python scripts/config_hashes.py > before.txt   # ... change the registry ...
    python scripts/config_hashes.py > after.txt && diff before.txt after.txt

Each line is ``domain algo settings-hash tables-hash``: the settings hash covers the spec's
dotted settings, training options, envs per learner, executor, multi-agent and env options; the
tables hash every tensor of the learner's state after 40 training steps of 2 seeds x 2 envs.
Registry changes that should not change what is learned must leave the file unchanged.
"""

from __future__ import annotations

import argparse
import hashlib
import warnings

import torch

import agents  # noqa: F401 (registers the built-in domains)
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer


def _digest(value) -> str:
    return hashlib.sha256(repr(value).encode()).hexdigest()[:16]


def settings_hash(spec) -> str:
    """The spec as data: everything that decides what its runs learn, but the graph's code."""
    return _digest(
        (
            sorted(spec.settings().items()),
            spec.train,
            spec.envs_per_learner,
            spec.executor,
            spec.multiagent,
            sorted(spec.env_options.items()),
        )
    )


def tables_hash(domain, algo: str, steps: int) -> str:
    """The learner's tensors after ``steps`` steps of a tiny population."""
    opts = RunOptions(
        seeds=(0, 1), envs_per_learner=2, steps=steps, eval_every=0, eval_episodes=0,
        progress=False, tensorboard=False, check_env=False,
    )
    trainer = build_trainer(domain, algo, opts)
    trainer.train()
    h = hashlib.sha256()
    for key, tensor in sorted(trainer.learner.state_dict().items()):
        if isinstance(tensor, torch.Tensor):
            h.update(key.encode())
            h.update(tensor.detach().cpu().contiguous().reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()[:16]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--domains", nargs="*", default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    for name in args.domains or registry.names():
        domain = registry.get(name)
        for algo in sorted(domain.algos):
            spec = domain.algos[algo]
            tables = tables_hash(domain, algo, args.steps)
            print(name, algo, settings_hash(spec), tables, flush=True)


if __name__ == "__main__":
    main()
