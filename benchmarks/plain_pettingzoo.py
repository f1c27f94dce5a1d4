"""Env steps per second of a PettingZoo AEC env stepped in plain Python with random actions.

The reference the batched multi-agent envs will be compared with: one Python ``step`` per agent
decision, the way a user's own PettingZoo loop runs. An *env step* is a joint decision epoch:
for ``hrl_torch.env.pettingzoo_env.MultiAgentAECEnv`` (also inside PettingZoo wrappers) it is read
from the env's ``epochs`` counter (batched env steps that carried decisions); for any other AEC
env it is estimated as agent decisions divided by the number of agents (exact for envs where
every agent acts once per epoch). Resets are timed but not counted: a batched env spends one
extra step per episode on its next-step auto-reset, which a comparison should count the same way.

Usage::

    PYTHONPATH=. .venv/bin/python -m benchmarks.plain_pettingzoo
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable

import gymnasium
from pettingzoo import AECEnv


def _epochs(env: AECEnv) -> int | None:
    """The env's own count of joint decision epochs, if it keeps one."""
    return getattr(env.unwrapped, "epochs", None)


def steps_per_second(aec_env_factory: Callable[[], AECEnv], n_steps: int, seed: int = 0) -> float:
    """Step a fresh AEC env for ``n_steps`` joint decision epochs; return epochs per second.

    Actions are uniform over each agent's action space (or over its ``action_mask`` when the
    observation or info has one); episodes restart with ``reset()`` until ``n_steps`` epochs
    are done. The clock includes the resets.

    Args:
        aec_env_factory: builds the env (not yet reset).
        n_steps: joint decision epochs to run.
        seed: seeds the first ``reset`` and the action sampler.

    Returns:
        Joint decision epochs per second of wall-clock time.
    """
    env = aec_env_factory()
    rng = random.Random(seed)
    start = time.perf_counter()
    env.reset(seed=seed)
    first = _epochs(env)
    decisions = epochs = 0
    while epochs < n_steps:
        if not env.agents:
            env.reset()
            continue
        agent = env.agent_selection
        obs, _, terminated, truncated, info = env.last()
        if terminated or truncated:
            env.step(None)
            continue
        space = env.action_space(agent)
        mask = obs.get("action_mask") if isinstance(obs, dict) else None
        mask = info.get("action_mask", mask)
        if mask is not None:
            action = rng.choice([a for a, ok in enumerate(mask) if ok])
        elif isinstance(space, gymnasium.spaces.Discrete):
            action = int(space.start) + rng.randrange(int(space.n))
        else:
            action = space.sample()
        env.step(action)
        decisions += 1
        epochs = (_epochs(env) - first) if first is not None else decisions // env.max_num_agents
    seconds = time.perf_counter() - start
    env.close()
    return epochs / max(seconds, 1e-9)


if __name__ == "__main__":
    import os
    import sys

    import torch

    os.environ.setdefault("RL_LOGGING_LEVEL", "WARNING")
    torch.set_num_threads(1)
    sys.path.insert(0, ".")
    from hrl_torch.env.pettingzoo_env import make_aec
    from tests.helpers_multiagent import AsyncToyEnv, SyncToyEnv  # until Chapter 6's domains

    for cls in (AsyncToyEnv, SyncToyEnv):
        rate = steps_per_second(lambda cls=cls: make_aec(cls), 2_000)
        print(f"{cls.__name__}: {rate:,.0f} env steps/s (plain PettingZoo AEC loop)")
