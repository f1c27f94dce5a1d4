"""A torch-batched domain as a TorchRL ``EnvBase`` (for collectors and ``check_env_specs``).

TorchRL resets finished rows explicitly (``_reset`` masks), so this wrapper drives the domain's
``_reset_rows`` / ``_step_all`` hooks directly instead of its next-step auto-reset. TorchRL is
imported here and in the collector module only.
"""

from __future__ import annotations

import inspect

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from hrl_torch.env.batched import BatchedEnv


def init_signature(cls: type) -> type:
    """``cls`` with ``__init__``'s signature as its own (class decorator).

    TorchRL's ``EnvBase`` has a metaclass whose ``__call__(*args, **kwargs)`` is what
    ``inspect.signature`` and ``help`` would show as an ``EnvBase`` subclass's constructor.
    """
    params = list(inspect.signature(cls.__init__).parameters.values())[1:]  # (without self)
    cls.__signature__ = inspect.Signature(params)
    return cls


@init_signature
class TorchRLEnv(EnvBase):
    """Wrap a ``BatchedEnv`` (any batch size) as a TorchRL env with specs.

    Observation keys are the domain's declared fields; ``duration`` (time of the step) is an
    extra observation so continuous-time learners can read it from collector rollouts.
    ``TorchRLEnv(env)``: ``batch_size`` and ``device`` are the env's; a discrete action space
    becomes a ``Categorical`` spec, a continuous one (``action_bounds``) a ``Bounded`` one.

    Args:
        env: the domain (a ``BatchedEnv`` of any batch size).

    Example:
        ``TorchRLEnv(TaxiEnv([0, 1], 3)).rollout(10)``: 2 seeds x 3 rows; TorchRL's
        ``check_env_specs`` passes on it and the other domains' envs (``tests/envs/``).
    """

    def __init__(self, env: BatchedEnv) -> None:
        super().__init__(batch_size=torch.Size([env.batch_size]), device=env.device)
        self.env = env
        b = env.batch_size
        obs = {
            k: Categorical(n, shape=(b,), dtype=torch.long, device=env.device)
            for k, n in env.observation_sizes.items()
        }
        for k, (low, high) in env.observation_bounds.items():
            low_t = torch.tensor(low, dtype=torch.float32)
            high_t = torch.tensor(high, dtype=torch.float32)
            obs[k] = Bounded(
                low_t.expand(b, *low_t.shape),
                high_t.expand(b, *high_t.shape),
                shape=(b, *low_t.shape),
                device=env.device,
            )
        obs["duration"] = Unbounded(shape=(b,), dtype=torch.float32, device=env.device)
        self.observation_spec = Composite(obs, shape=(b,), device=env.device)
        if env.n_actions is not None:
            self.action_spec = Categorical(
                env.n_actions, shape=(b,), dtype=torch.long, device=env.device
            )
        else:
            low, high = (torch.tensor(x, dtype=torch.float32) for x in env.action_bounds)
            self.action_spec = Bounded(
                low.expand(b, *low.shape),
                high.expand(b, *high.shape),
                shape=(b, *low.shape),
                device=env.device,
            )
        self.reward_spec = Unbounded(shape=(b, 1), device=env.device)
        flag = dict(n=2, shape=(b, 1), dtype=torch.bool, device=env.device)
        self.done_spec = Composite(
            done=Categorical(**flag),
            terminated=Categorical(**flag),
            truncated=Categorical(**flag),
            shape=(b,),
            device=env.device,
        )

    def _fields(self, duration: torch.Tensor) -> dict:
        fields = {
            k: v
            for k, v in self.env.observation().items()
            if k in self.env.observation_sizes or k in self.env.observation_bounds
        }
        fields["duration"] = duration
        return fields

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        b = self.env.batch_size
        mask = torch.ones(b, dtype=torch.bool, device=self.device)
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict["_reset"].reshape(b)
        self.env.reset_rows(mask)
        self.env.elapsed[mask] = 0
        false = torch.zeros(b, 1, dtype=torch.bool, device=self.device)
        out = self._fields(torch.zeros(b, device=self.device))
        out.update(done=false, terminated=false.clone(), truncated=false.clone())
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict["action"]
        reward, duration, terminated = self.env.step_all(action)
        self.env.elapsed += 1
        limit = self.env.max_episode_steps
        truncated = (
            (self.env.elapsed >= limit) if limit is not None else torch.zeros_like(terminated)
        )
        truncated = truncated & ~terminated
        out = self._fields(duration.float())
        out.update(
            reward=reward.float().unsqueeze(-1),
            terminated=terminated.unsqueeze(-1),
            truncated=truncated.unsqueeze(-1),
            done=(terminated | truncated).unsqueeze(-1),
        )
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _set_seed(self, seed: int | None) -> None:
        from hrl_torch.common.rng import BatchRNG

        seeds = [int(seed or 0) + k for k in range(self.env.n_learners)]
        self.env.rng = BatchRNG(seeds, self.env.envs_per_learner, "env", self.env.device)
