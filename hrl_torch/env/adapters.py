"""Adapters between gymnasium envs and the batched interface of ``hrl_torch.env.batched``.

``GymnasiumBatchEnv`` runs a list of unmodified gymnasium envs (one Python ``step`` each, the
slower path) behind the same interface as the torch-batched domains, so a hierarchy written for
a batched domain runs on, e.g., gymnasium's own ``Taxi-v4``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict

Decoder = Callable[[torch.Tensor], dict[str, torch.Tensor]]


class GymnasiumBatchEnv:
    """``P * E`` gymnasium envs stepped in a loop, with next-step auto-reset.

    Args:
        make_env: builds one gymnasium env (e.g. ``lambda: gymnasium.make("Taxi-v4")``).
        seeds: one seed per learner; env ``e`` of learner ``p`` is first reset with seed
            ``seeds[p] * 100_003 + e`` and then continues its own generator.
        envs_per_learner: ``E``.
        decode: maps the stacked observations ``[B, ...]`` to the observation fields the
            hierarchy reads (default: ``{"observation": obs}``; a ``Dict`` observation space:
            its fields, each stacked).

    Raises:
        ValueError: an action space other than ``Discrete``, or an observation space that
            cannot be stacked (a ``Tuple``, a nested ``Dict``).
    """

    #: no counter-based random stream to restart (each gymnasium env keeps its own generator)
    rng = None
    #: rows cannot be split off (``BatchedEnv.subset_safe``)
    subset_safe = False
    #: one agent per row; no declared observation fields (``BatchedEnv``'s declarations)
    n_agents = None
    observation_sizes: dict = {}
    observation_bounds: dict = {}

    def __init__(
        self,
        make_env: Callable[[], gym.Env],
        seeds: Sequence[int],
        envs_per_learner: int,
        decode: Decoder | None = None,
    ) -> None:
        self.seeds = [int(s) for s in seeds]
        self.envs_per_learner = envs_per_learner
        self.n_learners = len(self.seeds)
        self.batch_size = self.n_learners * envs_per_learner
        self.device = torch.device("cpu")
        self.envs = [make_env() for _ in range(self.batch_size)]
        space = self.envs[0].action_space
        if not isinstance(space, gym.spaces.Discrete):
            raise ValueError(
                f"GymnasiumBatchEnv needs a Discrete action space (the hierarchy's primitives "
                f"are action indices), got {space}: discretize it with a gymnasium "
                "ActionWrapper, or write a BatchedEnv with action_bounds"
            )
        self.n_actions = int(space.n)
        observed = self.envs[0].observation_space
        if not isinstance(observed, gym.spaces.Box | gym.spaces.Discrete | gym.spaces.MultiDiscrete
                          | gym.spaces.MultiBinary | gym.spaces.Dict):  # fmt: skip
            raise ValueError(
                f"GymnasiumBatchEnv stacks Box, Discrete or Dict observations, got {observed}: "
                "wrap the env with gymnasium.wrappers.FlattenObservation"
            )
        self._keys = list(observed.spaces) if isinstance(observed, gym.spaces.Dict) else None
        if self._keys is not None and any(
            isinstance(observed[k], gym.spaces.Dict | gym.spaces.Tuple) for k in self._keys
        ):
            raise ValueError(
                f"GymnasiumBatchEnv stacks a Dict of Box or Discrete fields, got {observed}: "
                "wrap the env with gymnasium.wrappers.FlattenObservation"
            )
        default = (lambda obs: dict(obs)) if self._keys is not None else None
        self.decode = decode or default or (lambda obs: {"observation": obs})
        self.done = torch.zeros(self.batch_size, dtype=torch.bool)
        self._obs: list = [None] * self.batch_size

    def to(self, device: torch.device | str) -> GymnasiumBatchEnv:
        """Hand out the observations on ``device`` (the gymnasium envs stay in Python)."""
        self.device = torch.device(device)
        return self

    def learner_of_row(self) -> torch.Tensor:
        """Learner index of every row: ``[B]``."""
        return torch.arange(self.batch_size, device=self.device) // self.envs_per_learner

    def reset(self) -> TensorDict:
        """Reset every env (seeded on the first call)."""
        for b, env in enumerate(self.envs):
            p, e = divmod(b, self.envs_per_learner)
            self._obs[b], _ = env.reset(seed=self.seeds[p] * 100_003 + e)
        self.done.zero_()
        zeros = torch.zeros(self.batch_size)
        flags = torch.zeros(self.batch_size, dtype=torch.bool)
        return self._output(zeros, flags, flags, torch.ones_like(flags))

    def step(self, action: torch.Tensor) -> TensorDict:
        """Step every env once; envs that ended on the previous step are reset instead."""
        action = torch.as_tensor(action).cpu().numpy()
        reward = np.zeros(self.batch_size, dtype=np.float32)
        terminated = np.zeros(self.batch_size, dtype=bool)
        truncated = np.zeros(self.batch_size, dtype=bool)
        is_init = self.done.numpy().copy()
        for b, env in enumerate(self.envs):
            if is_init[b]:
                self._obs[b], _ = env.reset()
                continue
            if not env.action_space.contains(env.action_space.dtype.type(action[b])):
                raise ValueError(f"action {action[b]} outside {env.action_space} (env row {b})")
            self._obs[b], r, terminated[b], truncated[b], _ = env.step(action[b])
            reward[b] = r
        self.done = torch.from_numpy(terminated | truncated)
        return self._output(
            torch.from_numpy(reward),
            torch.from_numpy(terminated),
            torch.from_numpy(truncated),
            torch.from_numpy(is_init),
        )

    def _output(self, reward, terminated, truncated, is_init) -> TensorDict:
        if self._keys is not None:  # a Dict space: each field stacked on its own
            stacked = {k: torch.as_tensor(np.stack([o[k] for o in self._obs])) for k in self._keys}
        else:
            stacked = torch.as_tensor(np.stack(self._obs))
        fields = self.decode(stacked)
        fields.update(
            reward=reward.float(),
            duration=(~is_init).float(),
            terminated=terminated,
            truncated=truncated,
            is_init=is_init,
        )
        return TensorDict(fields, batch_size=[self.batch_size]).to(self.device)

    def state_dict(self) -> dict:
        """Gymnasium envs cannot be checkpointed exactly; resuming restarts their episodes."""
        return {}

    def load_state_dict(self, state: dict) -> None:
        """See ``state_dict``: nothing to restore."""


class BatchedToGymnasium(gym.Env):
    """One row of a torch-batched domain as a plain ``gymnasium.Env``.

    The observation space is a ``Dict`` of the env's declared fields (``Discrete`` for
    ``observation_sizes``, ``Box`` for ``observation_bounds``); the action space is
    ``Discrete(n_actions)`` or the ``Box`` of ``action_bounds``.

    Args:
        make_batched: ``(seeds, envs_per_learner) -> BatchedEnv``; called with one seed and one
            env.
        render_mode: unused (no rendering).
    """

    metadata = {"render_modes": []}

    def __init__(self, make_batched: Callable, render_mode: str | None = None) -> None:
        self._make = make_batched
        self._env = make_batched([0], 1)
        spaces = {k: gym.spaces.Discrete(n) for k, n in self._env.observation_sizes.items()}
        for k, (low, high) in self._env.observation_bounds.items():
            spaces[k] = gym.spaces.Box(np.array(low, np.float32), np.array(high, np.float32))
        self.observation_space = gym.spaces.Dict(spaces)
        if self._env.n_actions is not None:
            self.action_space = gym.spaces.Discrete(self._env.n_actions)
        else:
            low, high = self._env.action_bounds
            self.action_space = gym.spaces.Box(
                np.array(low, np.float32), np.array(high, np.float32)
            )
        self.render_mode = render_mode

    def _obs(self, td: TensorDict) -> dict:
        out = {}
        for k in self.observation_space.spaces:
            v = td[k][0].cpu().numpy()
            out[k] = np.int64(v) if k in self._env.observation_sizes else v.astype(np.float32)
        return out

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode (a new seed rebuilds the batched env's random stream)."""
        super().reset(seed=seed)
        if seed is not None:
            self._env = self._make([seed], 1)
        return self._obs(self._env.reset()), {}

    def step(self, action):
        """One step of the underlying row."""
        if not self.action_space.contains(np.asarray(action, dtype=self.action_space.dtype)):
            raise ValueError(f"action {action!r} outside {self.action_space}")
        if self._env.n_actions is not None:
            a = torch.tensor([int(action)])
        else:
            a = torch.as_tensor(np.asarray(action, np.float32)).reshape(1, -1)
        td = self._env.step(a)
        return (
            self._obs(td),
            float(td["reward"][0]),
            bool(td["terminated"][0]),
            bool(td["truncated"][0]),
            {"duration": float(td["duration"][0])},
        )
