"""One row of a ``MultiAgentBatchedEnv`` as a PettingZoo env (AEC or parallel API).

Users' own multi-agent algorithms step these like any PettingZoo env; the batched env stays the
fast path. Both adapters build the batched env with one seed and one env per learner through an
``env_factory(seeds, envs_per_learner)`` (the env class itself usually fits), name the agents
``agent_0 ... agent_{n-1}`` and give every agent the same spaces:

- observation: a ``gymnasium.spaces.Dict`` of the agent's own fields (``_observe_agents``:
  ``Discrete`` for ``agent_observation_sizes``, ``Box`` otherwise) and the row's *declared*
  shared fields (``Discrete`` for ``observation_sizes``, ``Box`` for ``observation_bounds``).
  Shared fields the env does not declare (``assemblies_delivered``, ``out_of_fuel``, ...) are
  per-step metrics, as in ``hrl_torch.env.adapters``: they go to ``infos``;
- action: ``Discrete(n_actions)``; an action outside it raises a one-line ``ValueError`` and
  leaves the env unchanged;
- ``infos[agent]``: ``duration`` (time since the agent's action started, when it acts; 0 for an
  agent whose action still runs), ``team_reward`` and ``step_duration`` (the row's reward and
  elapsed time at the last step) and the undeclared shared fields;
- ``terminations`` / ``truncations``: the row's flags, the same for every agent (all agents of a
  row end together).

``reset(seed=s)`` rebuilds the batched env with seed ``s``, so equal seeds give equal
episodes. ``reset()`` after an episode's end takes the batched env's own auto-reset step, so the
episodes that follow are exactly those of row 0 of a batched env built with the same seed and
stepped with the same actions (``reset()`` in mid-episode calls the env's ``reset`` instead).

``MultiAgentAECEnv`` follows the asynchronous decisions of event-driven envs (tau_continue):
``agent_selection`` is always an agent that is ``acting``; the acting agents of a decision
epoch queue up in index order, each gives its action with ``step``, and the last one's ``step``
steps the batched env with the joint action (entries of agents that do not act are ignored by
the env). The next epoch's acting agents then queue up. Rewards are SMDP rewards:

- when the batched env steps, ``rewards[agent]`` is the agent's entry of ``agents.reward``: for
  an agent that acts at the new epoch, the team reward summed (undiscounted) since its previous
  action started; 0 for an agent whose action still runs. The other ``step`` calls of an epoch
  only buffer an action and give every agent 0;
- so ``last()`` at an agent's turn returns exactly the reward of its previous action
  (PettingZoo's ``_cumulative_rewards``, zeroed when the agent steps), and every agent sees
  every unit of team reward once. At the end of an episode every agent acts (running actions
  are cut), gets its share, and then takes PettingZoo's ``None`` dead step.

``MultiAgentParallelEnv`` is for synchronous envs, where every agent acts at every step (the
discrete-time domains): ``step(actions)`` with one action per live agent. The parallel API
cannot say "only some agents decide now", so an epoch where not every agent acts raises a
``RuntimeError`` pointing to the AEC env (the row has then moved on: reset or discard the env).
This is found when it happens, not at construction: ``MultiAgentBatchedEnv`` does not declare
whether it is synchronous.

Does not work: continuous actions (``action_bounds``), per-agent action masks, rendering
(``render`` returns ``None``), ``state()``. Within ``hrl_torch`` only this module imports
PettingZoo.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils.wrappers import OrderEnforcingWrapper
from tensordict import TensorDict

from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv

#: ``(seeds, envs_per_learner) -> MultiAgentBatchedEnv``
EnvFactory = Callable[[Sequence[int], int], MultiAgentBatchedEnv]


def _build(env_factory: EnvFactory, seed: int) -> MultiAgentBatchedEnv:
    """One row of the factory's env for ``seed``, checked."""
    env = env_factory([int(seed)], 1)
    if not isinstance(env, MultiAgentBatchedEnv):
        raise TypeError(f"env_factory must build a MultiAgentBatchedEnv, got {type(env)}")
    if env.batch_size != 1:
        raise ValueError(f"env_factory([seed], 1) built {env.batch_size} rows, expected 1")
    if env.n_actions is None:
        raise ValueError("continuous actions are not supported: n_actions is None")
    return env


def _box_like(value: np.ndarray) -> gym.spaces.Box:
    """An unbounded ``Box`` of the value's shape and dtype (float32 for floating fields)."""
    if value.dtype == np.bool_:
        return gym.spaces.Box(False, True, shape=value.shape, dtype=np.bool_)
    if np.issubdtype(value.dtype, np.integer):
        info = np.iinfo(np.int64)
        return gym.spaces.Box(info.min, info.max, shape=value.shape, dtype=np.int64)
    return gym.spaces.Box(-np.inf, np.inf, shape=value.shape, dtype=np.float32)


def _scalar(value: np.ndarray) -> Any:
    """A 0-d array as a Python number, anything else as is (for infos)."""
    return value.item() if value.ndim == 0 else value


def _one_line(action: Any) -> str:
    return " ".join(repr(action).split())


class _AgentView:
    """How one env row becomes per-agent observation dicts and infos.

    Args:
        env: the one-row batched env (its fields are read without a reset).
    """

    def __init__(self, env: MultiAgentBatchedEnv) -> None:
        own = {k: v[0, 0].cpu().numpy() for k, v in env.agent_observation().items()}
        shared = {k: v[0].cpu().numpy() for k, v in env.observation().items()}
        clash = sorted(set(own) & set(shared))
        if clash:
            raise ValueError(f"agent and shared observation fields share the names {clash}")
        self.agent_spaces: dict[str, gym.Space] = {}
        for key, value in own.items():
            size = env.agent_observation_sizes.get(key)
            space = _box_like(value) if size is None else gym.spaces.Discrete(size)
            self.agent_spaces[key] = space
        self.shared_spaces: dict[str, gym.Space] = {}
        for key, size in env.observation_sizes.items():
            self.shared_spaces[key] = gym.spaces.Discrete(size)
        for key, (low, high) in env.observation_bounds.items():
            low, high = np.array(low, np.float32), np.array(high, np.float32)
            self.shared_spaces[key] = gym.spaces.Box(low, high, dtype=np.float32)
        self.metric_keys = [k for k in shared if k not in self.shared_spaces]

    def space(self) -> gym.spaces.Dict:
        """A new observation space (one object per agent, so each can be seeded)."""
        return gym.spaces.Dict({**self.agent_spaces, **self.shared_spaces})

    @staticmethod
    def _value(space: gym.Space, value: np.ndarray) -> Any:
        if isinstance(space, gym.spaces.Discrete):
            return np.int64(value)
        return np.array(value, dtype=space.dtype)

    def observations(self, td: TensorDict) -> list[dict[str, Any]]:
        """Observation dict of every agent of the row ``td`` (batch ``[1]``)."""
        own = {k: td["agents", k][0].cpu().numpy() for k in self.agent_spaces}
        shared = {k: td[k][0].cpu().numpy() for k in self.shared_spaces}
        return [
            {
                **{k: self._value(s, own[k][j]) for k, s in self.agent_spaces.items()},
                **{k: self._value(s, shared[k]) for k, s in self.shared_spaces.items()},
            }
            for j in range(td["agents"].shape[1])
        ]

    def infos(self, td: TensorDict) -> list[dict[str, Any]]:
        """Info dict of every agent of the row ``td`` (see the module docstring)."""
        common = {
            "team_reward": float(td["reward"][0]),
            "step_duration": float(td["duration"][0]),
        }
        common.update({k: _scalar(td[k][0].cpu().numpy()) for k in self.metric_keys})
        durations = td["agents", "duration"][0].tolist()
        return [{"duration": float(d), **common} for d in durations]


class _RowAdapter:
    """What both PettingZoo adapters share: the row, its agents and their spaces."""

    def _setup(self, env_factory: EnvFactory, seed: int, render_mode: str | None) -> None:
        self._factory = env_factory
        self._env = _build(env_factory, seed)
        self._view = _AgentView(self._env)
        n = self._env.n_agents
        self.possible_agents = [f"agent_{j}" for j in range(n)]
        self._index = {agent: j for j, agent in enumerate(self.possible_agents)}
        self.observation_spaces = {a: self._view.space() for a in self.possible_agents}
        self.action_spaces = {
            a: gym.spaces.Discrete(self._env.n_actions) for a in self.possible_agents
        }
        self.render_mode = render_mode
        self.agents: list[str] = []
        #: batched env steps (joint decision epochs) since construction
        self.epochs = 0

    @property
    def batched_env(self) -> MultiAgentBatchedEnv:
        """The wrapped one-row batched env."""
        return self._env

    def observation_space(self, agent: str) -> gym.Space:
        """The agent's observation ``Dict`` (the same object at every call)."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gym.Space:
        """``Discrete(n_actions)`` (the same object at every call)."""
        return self.action_spaces[agent]

    def _reset_row(self, seed: int | None) -> TensorDict:
        """A new seeded env, the row's own auto-reset after an episode's end, or ``reset``."""
        if seed is not None:
            env = _build(self._factory, seed)
            if (env.n_agents, env.n_actions) != (self._env.n_agents, self._env.n_actions):
                raise ValueError(f"env_factory([{seed}], 1) changed the agents or actions")
            self._env = env
        elif bool(self._env.done[0]):
            # the step after an end resets the row (actions ignored), as in the batched env
            return self._env.step(torch.zeros(1, self._env.n_agents, dtype=torch.long))
        return self._env.reset()

    def _action(self, agent: str, action: Any) -> int:
        """The action as an int; a one-line ``ValueError`` when it is outside the space."""
        space = self.action_spaces[agent]
        if isinstance(action, torch.Tensor) and action.numel() == 1:
            action = action.item()
        if action is None or not space.contains(action):
            raise ValueError(
                f"invalid action {_one_line(action)} for {agent}: expected an integer in "
                f"[0, {space.n})"
            )
        return int(action)

    def render(self) -> None:
        """No rendering."""
        return None

    def close(self) -> None:
        """Nothing to release."""


class MultiAgentAECEnv(_RowAdapter, AECEnv):
    """A one-row ``MultiAgentBatchedEnv`` as a PettingZoo AEC env (see the module docstring).

    Args:
        env_factory: ``(seeds, envs_per_learner) -> MultiAgentBatchedEnv``.
        seed: the seed of the first episodes (until ``reset(seed=...)``).
        render_mode: unused (no rendering).
    """

    metadata = {"render_modes": [], "name": "hrl_multiagent_aec_v0", "is_parallelizable": False}

    def __init__(
        self, env_factory: EnvFactory, seed: int = 0, render_mode: str | None = None
    ) -> None:
        AECEnv.__init__(self)
        self._setup(env_factory, seed, render_mode)
        self._joint = torch.zeros(1, self._env.n_agents, dtype=torch.long)
        self._queue: list[str] = []
        self._obs: list[dict[str, Any]] = []

    def reset(self, seed: int | None = None, options: dict | None = None) -> None:
        """Start an episode; every agent acts first, in index order."""
        td = self._reset_row(seed)
        self.agents = list(self.possible_agents)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self._skip_agent_selection = None
        self._load(td)

    def observe(self, agent: str) -> dict[str, Any]:
        """The agent's observation at the current decision epoch."""
        return dict(self._obs[self._index[agent]])

    def step(self, action: Any) -> None:
        """Give ``agent_selection``'s action; the epoch's last action steps the batched env."""
        if not self.agents:
            raise RuntimeError("no live agents: call reset() to start an episode")
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            self._was_dead_step(action)
            return
        self._joint[0, self._index[agent]] = self._action(agent, action)
        self._cumulative_rewards[agent] = 0.0
        self._queue.pop(0)
        if self._queue:
            self._clear_rewards()
            self.agent_selection = self._queue[0]
        else:
            td = self._env.step(self._joint)
            self.epochs += 1
            self._load(td)
        self._accumulate_rewards()

    def _load(self, td: TensorDict) -> None:
        """Read a new decision epoch: rewards, flags, infos, observations, who acts."""
        self._obs = self._view.observations(td)
        infos = self._view.infos(td)
        reward = td["agents", "reward"][0].tolist()
        terminated, truncated = bool(td["terminated"][0]), bool(td["truncated"][0])
        self.rewards = {a: float(reward[self._index[a]]) for a in self.agents}
        self.terminations = dict.fromkeys(self.agents, terminated)
        self.truncations = dict.fromkeys(self.agents, truncated)
        self.infos = {a: infos[self._index[a]] for a in self.agents}
        if terminated or truncated:
            self._queue = []
            self.agent_selection = self.agents[0]
            return
        acting = td["agents", "acting"][0].tolist()
        self._queue = [a for a in self.agents if acting[self._index[a]]]
        if not self._queue:
            raise RuntimeError(
                f"{type(self._env).__name__} reported a live decision epoch where no agent acts"
            )
        self.agent_selection = self._queue[0]


class MultiAgentParallelEnv(_RowAdapter, ParallelEnv):
    """A one-row synchronous ``MultiAgentBatchedEnv`` as a PettingZoo parallel env.

    Args:
        env_factory: ``(seeds, envs_per_learner) -> MultiAgentBatchedEnv``; every agent must
            act at every step.
        seed: the seed of the first episodes (until ``reset(seed=...)``).
        render_mode: unused (no rendering).
    """

    metadata = {"render_modes": [], "name": "hrl_multiagent_parallel_v0"}

    def __init__(
        self, env_factory: EnvFactory, seed: int = 0, render_mode: str | None = None
    ) -> None:
        self._setup(env_factory, seed, render_mode)

    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, Any], dict[str, dict]]:
        """Start an episode: ``(observations, infos)`` of every agent."""
        td = self._reset_row(seed)
        self.agents = list(self.possible_agents)
        return self._per_agent(self._view.observations(td)), self._per_agent(self._view.infos(td))

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """One step with every live agent's action (all agents of a live row act).

        Returns:
            ``(observations, rewards, terminations, truncations, infos)`` keyed by the agents
            that were live; after the episode's last step ``agents`` is empty.
        """
        if not self.agents:
            raise RuntimeError("no live agents: call reset() to start an episode")
        if set(actions) != set(self.agents):
            missing = sorted(set(self.agents) - set(actions))
            extra = sorted(set(actions) - set(self.agents))
            raise ValueError(
                f"actions must name every live agent: missing {missing}, extra {extra}"
            )
        joint = torch.zeros(1, self._env.n_agents, dtype=torch.long)
        for agent, action in actions.items():
            joint[0, self._index[agent]] = self._action(agent, action)
        td = self._env.step(joint)
        self.epochs += 1
        terminated, truncated = bool(td["terminated"][0]), bool(td["truncated"][0])
        acting = td["agents", "acting"][0]
        if not (terminated or truncated or bool(acting.all())):
            idle = [
                a for a, act in zip(self.possible_agents, acting.tolist(), strict=True) if not act
            ]
            raise RuntimeError(
                f"{type(self._env).__name__} is asynchronous: after step {self.epochs} "
                f"{idle} do not act; the parallel API needs every agent to act at every "
                "step, use MultiAgentAECEnv"
            )
        reward = td["agents", "reward"][0].tolist()
        out = (
            self._per_agent(self._view.observations(td)),
            {a: float(reward[self._index[a]]) for a in self.agents},
            dict.fromkeys(self.agents, terminated),
            dict.fromkeys(self.agents, truncated),
            self._per_agent(self._view.infos(td)),
        )
        if terminated or truncated:
            self.agents = []
        return out

    def _per_agent(self, values: list) -> dict[str, Any]:
        return {a: values[self._index[a]] for a in self.agents}


def make_aec(env_factory: EnvFactory, seed: int = 0) -> AECEnv:
    """A ``MultiAgentAECEnv`` in PettingZoo's ``OrderEnforcingWrapper``, not yet reset.

    The wrapper is how PettingZoo ships its own envs: using the env before ``reset`` raises a
    clear error.

    Args:
        env_factory: ``(seeds, envs_per_learner) -> MultiAgentBatchedEnv``.
        seed: the seed of the first episodes.

    Returns:
        The wrapped env; ``.unwrapped`` is the ``MultiAgentAECEnv``.
    """
    return OrderEnforcingWrapper(MultiAgentAECEnv(env_factory, seed))
