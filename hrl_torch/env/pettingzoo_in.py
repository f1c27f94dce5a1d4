"""An existing PettingZoo env, as it is, as a ``MultiAgentBatchedEnv`` hrl-torch trains on.

``PettingZooBatchedEnv(make_env, seeds, envs_per_learner)`` holds ``B = P * E`` copies of the
env ``make_env()`` builds (a ``ParallelEnv``, or an ``AECEnv``, which
``pettingzoo.utils.conversions.aec_to_parallel`` turns into one) and steps them as the rows of
one batched env, so every multi-agent learner here (selfish, cooperative, per-agent flat Q on a
one-level graph) and the ``Trainer`` take it as they take a torch domain.

The copies are Python objects: every step and reset is a Python loop over them, the only way
into an env written for one episode at a time. That loop is here, in the adapter of a foreign
env, and nowhere in hrl-torch's own hot path (its torch domains step all rows at once); expect
the env's own speed times ``B``.

What the batched env shows:

- agents: ``env.possible_agents`` in order, agent ``j`` of a row is ``possible_agents[j]``;
- each agent's observation is its field ``observation``: an integer ``[B, n]`` for a
  ``Discrete`` space (declared in ``agent_observation_sizes``), a float ``[B, n, *shape]`` for a
  ``Box``; other spaces are refused. No shared fields;
- actions: every agent's space must be the same ``Discrete(k)``;
- rewards: each agent's own reward, ``[B, n]`` (so the row's team reward is their sum);
- episodes: a row ends when no agent is left in its copy (``env.agents`` empty): terminated
  when an agent terminated, else truncated by the env's own time limit, which must be the
  adapter's ``max_episode_steps`` (default: the env's ``max_cycles``, where it has one); an
  agent that leaves early acts no more (its reward is 0 from then on, its observation the last);
- random numbers: each episode of a row starts with ``reset(seed=...)``, the seed drawn from the
  row's own stream (``self.rng``), so a seed's episodes do not depend on its population.

A copy's state is the foreign env's own Python state, so it is not saved: ``state_dict()`` is
empty (checkpoints hold the learner; a resumed run starts new episodes) and ``check_env`` does
not ask for a replay.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv


def as_parallel(env):
    """``env`` as a PettingZoo ``ParallelEnv`` (an ``AECEnv`` through ``aec_to_parallel``)."""
    from pettingzoo.utils.env import AECEnv, ParallelEnv

    if isinstance(env, ParallelEnv):
        return env
    if isinstance(env, AECEnv):
        from pettingzoo.utils.conversions import aec_to_parallel

        return aec_to_parallel(env)
    raise TypeError(f"make_env must build a PettingZoo ParallelEnv or AECEnv, got {type(env)}")


class PettingZooBatchedEnv(MultiAgentBatchedEnv):
    """``B`` copies of an existing PettingZoo env as one ``MultiAgentBatchedEnv`` (module doc).

    Args:
        make_env: builds one copy (``lambda: simple_spread_v3.parallel_env(N=2)``).
        seeds: one seed per learner.
        envs_per_learner: ``E`` copies per learner.
        max_episode_steps: the time limit in steps; ``None``: the env's ``max_cycles``.
        device: where the batched fields live.
    """

    def __init__(
        self,
        make_env: Callable[[], object],
        seeds: Sequence[int],
        envs_per_learner: int,
        max_episode_steps: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        from gymnasium import spaces

        copies = [as_parallel(make_env()) for _ in range(len(seeds) * envs_per_learner)]
        names = list(copies[0].possible_agents)
        act = copies[0].action_space(names[0])
        if not isinstance(act, spaces.Discrete) or any(
            copies[0].action_space(a) != act for a in names
        ):
            raise ValueError(f"every agent needs the same Discrete action space, got {act}")
        obs = copies[0].observation_space(names[0])
        if not isinstance(obs, (spaces.Discrete, spaces.Box)) or any(
            copies[0].observation_space(a) != obs for a in names
        ):
            raise ValueError(f"observations must be one Discrete or Box space, got {obs}")
        if max_episode_steps is None:
            max_episode_steps = getattr(copies[0].unwrapped, "max_cycles", None)
        n_actions = int(act.n)
        super().__init__(seeds, envs_per_learner, len(names), n_actions, max_episode_steps, device)
        self.copies, self.names, self.obs_space = copies, names, obs
        if isinstance(obs, spaces.Discrete):
            self.agent_observation_sizes = {"observation": int(obs.n)}
        shape = () if isinstance(obs, spaces.Discrete) else tuple(obs.shape)
        dtype = torch.long if isinstance(obs, spaces.Discrete) else torch.float32
        self.obs = torch.zeros((self.batch_size, self.n_agents, *shape), dtype=dtype)

    def _write(self, b: int, observations: dict) -> None:
        """Row ``b``'s observations into ``self.obs`` (agents that left keep their last)."""
        for j, name in enumerate(self.names):
            if name in observations:
                self.obs[b, j] = torch.as_tensor(np.asarray(observations[name]))

    def _reset_rows(self, mask: torch.Tensor) -> None:
        seeds = self.rng.integers(2**31 - 1).tolist()  # drawn for every row, used where reset
        for b in mask.cpu().nonzero().flatten().tolist():
            observations, _ = self.copies[b].reset(seed=int(seeds[b]))
            self._write(b, observations)

    def _step_all(self, action: torch.Tensor, acting: torch.Tensor):
        reward = torch.zeros(self.batch_size, self.n_agents)
        ended = torch.zeros(self.batch_size, dtype=torch.bool)
        actions = action.cpu().tolist()
        for b in (~self.done).cpu().nonzero().flatten().tolist():  # a done row is reset next
            env = self.copies[b]
            live = list(env.agents)
            observations, rewards, terms, truncs, _ = env.step(
                {a: actions[b][self.names.index(a)] for a in live}
            )
            self._write(b, observations)
            for a, r in rewards.items():
                reward[b, self.names.index(a)] = float(r)
            if env.agents:
                continue
            if any(terms.get(a, False) for a in live):
                ended[b] = True
            elif int(self.elapsed[b]) + 1 != self.max_episode_steps:
                raise ValueError(
                    f"the PettingZoo env truncated row {b} at step {int(self.elapsed[b]) + 1}, "
                    f"but max_episode_steps is {self.max_episode_steps}: pass the env's limit"
                )
        every = torch.ones(self.batch_size, self.n_agents, dtype=torch.bool)
        duration = torch.ones(self.batch_size)
        to = self.device
        return reward.to(to), duration.to(to), ended.to(to), every.to(to)

    def _observe(self) -> dict:
        return {}

    def _observe_agents(self) -> dict:
        return {"observation": self.obs.to(self.device).clone()}

    def state_dict(self) -> dict:
        """Empty: a foreign env's Python state is not saved (the module docstring)."""
        return {}

    def load_state_dict(self, state: dict) -> None:
        """Accept the empty ``state_dict`` (a resumed run starts new episodes)."""
        if state:
            raise ValueError("a PettingZooBatchedEnv restores no state: its state_dict is empty")
