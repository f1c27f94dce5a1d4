"""Adapters between gymnasium envs and the batched interface of ``hrl_torch.env.batched``.

``GymnasiumBatchEnv`` runs a list of unmodified gymnasium envs (one Python ``step`` each, the
slower path) behind the same interface as the torch-batched domains, so a hierarchy written for
a batched domain runs on, e.g., gymnasium's own ``Taxi-v4``.

Spaces. Observations of any of gymnasium's array spaces (``Discrete``, ``Box``,
``MultiDiscrete``, ``MultiBinary``) and of ``Dict`` / ``Tuple`` spaces of them come in as they
are: each row's observations are stacked into tensors, a ``Dict`` into one field per key (a
nested ``Dict`` nested), a ``Tuple`` into fields ``"0"``, ``"1"``, .... The abstraction hook
is ``decode``: it maps those stacked observations to the fields the hierarchy's subtasks read
(e.g. a ``MultiDiscrete`` observation to one integer state). Actions: ``Discrete``
(``n_actions``) or a ``Box`` of any shape (``action_bounds``: its low and high as nested
lists; the executor's action rows ``[B, *shape]`` are handed to the envs as they are).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict

Decoder = Callable[[torch.Tensor | dict], dict[str, torch.Tensor]]


def stack_observations(observations: list, space: gym.Space) -> torch.Tensor | dict:
    """Rows' observations of ``space`` as a tensor ``[B, ...]``, or a dict of them.

    ``Dict`` spaces give a dict by key (nested for a nested ``Dict``), ``Tuple`` spaces a dict
    by position (``"0"``, ``"1"``, ...); every other space one stacked tensor.
    """
    if isinstance(space, gym.spaces.Dict):
        return {
            k: stack_observations([o[k] for o in observations], sub) for k, sub in space.items()
        }
    if isinstance(space, gym.spaces.Tuple):
        parts = enumerate(space.spaces)
        return {str(i): stack_observations([o[i] for o in observations], sub) for i, sub in parts}
    return torch.as_tensor(np.stack([np.asarray(o) for o in observations]))


class GymnasiumBatchEnv:
    """``P * E`` gymnasium envs stepped in a loop, with next-step auto-reset.

    Args:
        make_env: builds one gymnasium env (e.g. ``lambda: gymnasium.make("Taxi-v4")``).
        seeds: one seed per learner; env ``e`` of learner ``p`` is first reset with seed
            ``seeds[p] * 100_003 + e`` and then continues its own generator.
        envs_per_learner: ``E``.
        decode: the abstraction hook: maps the stacked observations (``[B, ...]``, or a
            dict of them for a ``Dict`` / ``Tuple`` space: ``stack_observations``) to the
            observation fields the hierarchy reads (default: a dict as it is, a tensor as
            ``{"observation": obs}``).

    Raises:
        ValueError: an action space other than ``Discrete`` or ``Box`` (one line).
    """

    #: no counter-based random stream to restart (each gymnasium env keeps its own generator)
    rng = None
    #: rows cannot be split off (``BatchedEnv.subset_safe``)
    subset_safe = False
    #: one agent per row; no declared observation fields (``BatchedEnv``'s declarations)
    n_agents = None
    observation_sizes: dict = {}
    observation_bounds: dict = {}
    #: a ``Box`` action space's ``(low, high)`` as nested lists (``None``: ``Discrete``)
    action_bounds: tuple[list, list] | None = None

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
        if isinstance(space, gym.spaces.Discrete):
            self.n_actions = int(space.n)
        elif isinstance(space, gym.spaces.Box):
            self.n_actions = None
            self.action_bounds = (space.low.tolist(), space.high.tolist())
        else:
            raise ValueError(f"action space {space}: GymnasiumBatchEnv takes Discrete or Box")
        self.decode = decode or _default_decode
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
            space, a = env.action_space, action[b]
            if self.n_actions is None:  # a Box: the row's action array in the space's dtype
                a = np.asarray(a, dtype=space.dtype)
            if not space.contains(a if self.n_actions is None else space.dtype.type(a)):
                raise ValueError(f"action {action[b]} outside {space} (env row {b})")
            self._obs[b], r, terminated[b], truncated[b], _ = env.step(a)
            reward[b] = r
        self.done = torch.from_numpy(terminated | truncated)
        return self._output(
            torch.from_numpy(reward),
            torch.from_numpy(terminated),
            torch.from_numpy(truncated),
            torch.from_numpy(is_init),
        )

    def _output(self, reward, terminated, truncated, is_init) -> TensorDict:
        fields = dict(self.decode(stack_observations(self._obs, self.envs[0].observation_space)))
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


def _default_decode(obs: torch.Tensor | dict) -> dict:
    return obs if isinstance(obs, dict) else {"observation": obs}


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
