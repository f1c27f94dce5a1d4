"""A batched ``MultiAgentBatchedEnv`` as a TorchRL ``EnvBase`` with TorchRL's MARL layout.

The layout is that of TorchRL's ``PettingZooWrapper`` with one group, ``"agents"``: the env's
batch is ``[B]`` and the group's sub-TensorDict is ``[B, n]``.

- observations: the row's shared fields at the root (``Categorical`` for ``observation_sizes``,
  ``Bounded`` for ``observation_bounds``, ``Unbounded`` or boolean ``Categorical`` for the
  undeclared per-step metrics), plus ``duration`` (time the step advanced) and ``team_reward``
  (the row's reward of the step) ``[B]``; each agent's fields under ``"agents"`` ``[B, n]``
  (``Categorical`` for ``agent_observation_sizes``), plus ``("agents", "acting")`` (bool: the
  agent decides now; the others' actions are ignored, like PettingZoo's AEC ``mask``) and
  ``("agents", "duration")`` (time since the agent's action started, when it acts);
- action: ``("agents", "action")`` ``Categorical(n_actions)`` ``[B, n]``;
- reward: ``("agents", "reward")`` ``[B, n, 1]``: the agent's SMDP reward (the team reward
  summed since its action started, when it acts; 0 while its action runs);
- done: ``done`` / ``terminated`` / ``truncated`` ``[B, 1]`` at the root and
  ``("agents", ...)`` ``[B, n, 1]`` (the row's flags repeated: all agents of a row end
  together). ``truncated`` is cleared where ``terminated`` holds, as in
  ``hrl_torch.env.torchrl_env``.

Done handling: TorchRL's, not the env's next-step auto-reset. The flags above are the real
ones and TorchRL resets finished rows (``_reset`` masks, e.g. in ``rollout`` or a
``Collector``); a masked reset re-draws those rows through the env's ``_reset_rows`` hook and
restarts their agents (all acting, nothing pending). The step itself is the env's own ``step``,
so rewards, durations and ``acting`` are computed once, in ``MultiAgentBatchedEnv``. This is
the convention TorchRL's MARL losses and value estimators expect (the terminal observation is
in ``("next", ...)``), unlike ``hrl_torch.training.collector.AutoResetTorchRLEnv``, which hides the
ends so that the hierarchical executor sees terminal observations as policy inputs. If a finished
row is stepped without a reset, the env's auto-reset still applies: that step resets the row
and reports reward 0 and no done. Because TorchRL resets before the next step while the env's
auto-reset draws its numbers after that step's, a row's random stream follows the bare batched
env's only until its first end.

TorchRL is imported here, in ``hrl_torch.env.torchrl_env`` and in ``hrl_torch.training.collector``
only.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from hrl_torch.common.rng import BatchRNG
from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv
from hrl_torch.env.torchrl_env import init_signature

GROUP = "agents"
_DONE_KEYS = ("done", "terminated", "truncated")


def _field_spec(value: torch.Tensor, size: int | None = None, bounds=None):
    """Spec of an observation field with the shape and dtype of ``value``."""
    dev = value.device
    if size is not None:
        return Categorical(size, shape=value.shape, dtype=torch.long, device=dev)
    if bounds is not None:
        low, high = (torch.tensor(x, dtype=value.dtype, device=dev) for x in bounds)
        return Bounded(low.expand(value.shape), high.expand(value.shape), device=dev)
    if value.dtype == torch.bool:
        return Categorical(2, shape=value.shape, dtype=torch.bool, device=dev)
    return Unbounded(shape=value.shape, dtype=value.dtype, device=dev)


def _flags(shape: tuple[int, ...], device) -> dict[str, Categorical]:
    return {k: Categorical(2, shape=shape, dtype=torch.bool, device=device) for k in _DONE_KEYS}


@init_signature
class MultiAgentTorchRLEnv(EnvBase):
    """Wrap a ``MultiAgentBatchedEnv`` (any batch size) as a TorchRL multi-agent env.

    See the module docstring for the keys and the done handling. ``set_seed(s)`` re-seeds the
    env's random stream with seeds ``s, s + 1, ...`` (one per learner), as
    ``hrl_torch.env.torchrl_env.TorchRLEnv`` does.

    Args:
        env: the batched multi-agent env (discrete actions).
    """

    def __init__(self, env: MultiAgentBatchedEnv) -> None:
        if not isinstance(env, MultiAgentBatchedEnv):
            raise TypeError(f"env must be a MultiAgentBatchedEnv, got {type(env)}")
        if env.n_actions is None:
            raise ValueError("continuous actions are not supported: n_actions is None")
        super().__init__(batch_size=torch.Size([env.batch_size]), device=env.device)
        self.env = env
        b, n, dev = env.batch_size, env.n_agents, env.device
        shared = env.observation()
        own = env.agent_observation()
        self._shared_keys = list(shared)
        self._agent_keys = list(own)
        obs = {
            k: _field_spec(v, env.observation_sizes.get(k), env.observation_bounds.get(k))
            for k, v in shared.items()
        }
        obs["duration"] = Unbounded(shape=(b,), device=dev)
        obs["team_reward"] = Unbounded(shape=(b,), device=dev)
        agent_obs = {k: _field_spec(v, env.agent_observation_sizes.get(k)) for k, v in own.items()}
        agent_obs["acting"] = Categorical(2, shape=(b, n), dtype=torch.bool, device=dev)
        agent_obs["duration"] = Unbounded(shape=(b, n), device=dev)
        obs[GROUP] = Composite(agent_obs, shape=(b, n), device=dev)
        self.observation_spec = Composite(obs, shape=(b,), device=dev)
        action = Categorical(env.n_actions, shape=(b, n), dtype=torch.long, device=dev)
        self.full_action_spec = Composite(
            {GROUP: Composite(action=action, shape=(b, n), device=dev)}, shape=(b,), device=dev
        )
        reward = Unbounded(shape=(b, n, 1), device=dev)
        self.full_reward_spec = Composite(
            {GROUP: Composite(reward=reward, shape=(b, n), device=dev)}, shape=(b,), device=dev
        )
        self.full_done_spec = Composite(
            {
                **_flags((b, 1), dev),
                GROUP: Composite(_flags((b, n, 1), dev), shape=(b, n), device=dev),
            },
            shape=(b,),
            device=dev,
        )

    # -- TorchRL hooks
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = self._reset_mask(tensordict)
        return self._convert(self.env.restart_rows(mask), with_reward=False)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self._convert(self.env.step(tensordict.get((GROUP, "action"))), with_reward=True)

    def _set_seed(self, seed: int | None) -> None:
        seeds = [int(seed or 0) + k for k in range(self.env.n_learners)]
        self.env.rng = BatchRNG(seeds, self.env.envs_per_learner, "env", self.env.device)

    # -- helpers
    def _reset_mask(self, tensordict: TensorDictBase | None) -> torch.Tensor:
        """Rows to reset ``[B]``: from ``_reset`` (root or per agent), else every row."""
        b = self.env.batch_size
        if tensordict is not None:
            keys = tensordict.keys(include_nested=True)
            if "_reset" in keys:
                return tensordict.get("_reset").reshape(b)
            if (GROUP, "_reset") in keys:
                return tensordict.get((GROUP, "_reset")).reshape(b, -1).any(-1)
        return torch.ones(b, dtype=torch.bool, device=self.device)

    def _convert(self, out: TensorDict, with_reward: bool) -> TensorDict:
        """The env's output TensorDict in the layout of the specs."""
        b, n = self.env.batch_size, self.env.n_agents
        terminated = out["terminated"]
        flags = {
            "done": terminated | out["truncated"],
            "terminated": terminated,
            "truncated": out["truncated"] & ~terminated,
        }
        agents = out[GROUP]
        group = {k: agents[k] for k in self._agent_keys}
        group.update(acting=agents["acting"], duration=agents["duration"])
        group.update({k: v[:, None, None].expand(b, n, 1) for k, v in flags.items()})
        if with_reward:
            group["reward"] = agents["reward"].unsqueeze(-1)
        root = {k: out[k] for k in self._shared_keys}
        root.update(duration=out["duration"], team_reward=out["reward"])
        root.update({k: v.unsqueeze(-1) for k, v in flags.items()})
        root[GROUP] = TensorDict(group, batch_size=[b, n], device=self.device)
        return TensorDict(root, batch_size=[b], device=self.device)
