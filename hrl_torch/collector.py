"""Rollouts driven by ``torchrl.collectors.Collector``, with the hierarchical executor as policy.

TorchRL resets a finished row itself, and the policy's next input is then the new episode's
first observation: the terminal observation, which the executor needs to end every subtask and
emit its last transitions, would never reach it. So the domain keeps its own next-step
auto-reset (``hrl_torch.env``) and TorchRL sees an env that never ends:

- ``AutoResetTorchRLEnv`` wraps a ``BatchedEnv`` as an ``EnvBase`` whose ``done`` is always
  False; every observation carries the fields of the step that led to it (``step_reward``,
  ``step_duration``, ``step_terminated``, ``step_truncated``, ``is_init``), so after TorchRL's
  ``step_mdp`` the policy still sees them.
- ``HierarchicalPolicy`` is a ``TensorDictModuleBase`` that runs one step of the training loop
  in its ``forward``: ``HierarchicalAgent.step``, the step ``Trainer.train_step`` runs, so both
  paths learn the same tables from the same seeds.
- ``collect`` iterates a ``Collector`` over them until a stop condition holds; the collected
  frames are not needed for learning (the policy learns as it acts) and are dropped.

TorchRL is imported here and in ``hrl_torch.torchrl_env`` only.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.collectors import Collector
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from hrl_torch.agent import HierarchicalAgent
from hrl_torch.env import BatchedEnv
from hrl_torch.executor import ExecutorConfig
from hrl_torch.graph import TaskGraph
from hrl_torch.learners.base import Learner
from hrl_torch.rng import BatchRNG

#: the step fields of a BatchedEnv output, as observation keys (TorchRL keeps ``reward`` apart)
STEP_KEYS = {
    "reward": "step_reward",
    "duration": "step_duration",
    "terminated": "step_terminated",
    "truncated": "step_truncated",
    "is_init": "is_init",
}


def _fields(env: BatchedEnv) -> dict[str, torch.Tensor]:
    """The fields of the domain's step outputs, with their shapes and dtypes (no reset)."""
    b, dev = env.batch_size, env.device
    fields = dict(env._observe())
    fields.update(
        reward=torch.zeros(b, device=dev),
        duration=torch.zeros(b, device=dev),
        terminated=torch.zeros(b, dtype=torch.bool, device=dev),
        truncated=torch.zeros(b, dtype=torch.bool, device=dev),
        is_init=torch.zeros(b, dtype=torch.bool, device=dev),
    )
    return fields


def _spec_like(value: torch.Tensor, device) -> object:
    if value.dtype == torch.bool:
        return Categorical(2, shape=value.shape, dtype=torch.bool, device=device)
    return Unbounded(shape=value.shape, dtype=value.dtype, device=device)


class AutoResetTorchRLEnv(EnvBase):
    """A ``BatchedEnv`` as a TorchRL env that keeps the domain's next-step auto-reset.

    Every observation field of the domain is an observation key (declared sizes and bounds
    become ``Categorical`` / ``Bounded`` specs, the rest ``Unbounded``), plus ``STEP_KEYS``.
    ``done`` is always False: episodes end and restart inside the domain.
    """

    def __init__(self, env: BatchedEnv) -> None:
        super().__init__(batch_size=torch.Size([env.batch_size]), device=env.device)
        self.env = env
        sample = _fields(env)
        b, dev = env.batch_size, env.device
        obs = {}
        for key, value in sample.items():
            name = STEP_KEYS.get(key, key)
            if key in env.observation_sizes:
                obs[name] = Categorical(env.observation_sizes[key], shape=(b,), device=dev)
            elif key in env.observation_bounds:
                low, high = (
                    torch.tensor(x, dtype=torch.float32) for x in env.observation_bounds[key]
                )
                obs[name] = Bounded(
                    low.expand(b, *low.shape), high.expand(b, *high.shape), device=dev
                )
            else:
                obs[name] = _spec_like(value, dev)
        self.observation_spec = Composite(obs, shape=(b,), device=dev)
        if env.n_actions is not None:
            self.action_spec = Categorical(env.n_actions, shape=(b,), device=dev)
        else:
            low, high = (torch.tensor(x, dtype=torch.float32) for x in env.action_bounds)
            self.action_spec = Bounded(
                low.expand(b, *low.shape), high.expand(b, *high.shape), device=dev
            )
        self.reward_spec = Unbounded(shape=(b, 1), device=dev)
        flag = dict(n=2, shape=(b, 1), dtype=torch.bool, device=dev)
        self.done_spec = Composite(
            done=Categorical(**flag),
            terminated=Categorical(**flag),
            truncated=Categorical(**flag),
            shape=(b,),
            device=dev,
        )
        self._false = torch.zeros(b, 1, dtype=torch.bool, device=dev)
        self.resets = 0

    def _wrap(self, out: TensorDict) -> TensorDict:
        fields = {STEP_KEYS.get(k, k): v for k, v in out.items()}
        fields.update(done=self._false, terminated=self._false, truncated=self._false)
        return TensorDict(fields, batch_size=self.batch_size, device=self.device)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        self.resets += 1
        return self._wrap(self.env.reset())

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        out = self._wrap(self.env.step(tensordict["action"]))
        out["reward"] = out["step_reward"].unsqueeze(-1)
        return out

    def _set_seed(self, seed: int | None) -> None:
        """Seeds are the domain's (one per learner); TorchRL's seed is ignored."""


class HierarchicalPolicy(TensorDictModuleBase):
    """The executor and learner as a TorchRL policy: each call is one training step.

    Args:
        graph: the task graph.
        learner: the population learner.
        exploration: exploration of the training choices.
        env: the wrapped domain (its seeds, rows and learners).
        executor_config: guard and all-states options.
        on_batch: called as ``on_batch(batch, ctx)`` after each update (metrics).
    """

    def __init__(
        self,
        graph: TaskGraph,
        learner: Learner,
        exploration,
        env: BatchedEnv,
        executor_config: ExecutorConfig | None = None,
        on_batch: Callable | None = None,
    ) -> None:
        super().__init__()
        self.graph, self.learner = graph, learner
        rng = BatchRNG(env.seeds, env.envs_per_learner, "explore")
        self.agent = HierarchicalAgent(
            graph, learner, exploration, rng, env.envs_per_learner, executor_config
        )
        self.obs_keys = list(_fields(env).keys())
        self.in_keys = [STEP_KEYS.get(k, k) for k in self.obs_keys]
        self.out_keys = ["action"]
        self.on_batch = on_batch
        self._started = False

    @property
    def step(self) -> int:
        """Env steps per learner so far."""
        return self.agent.clock

    @property
    def executor(self):
        """The Task-Stack executor of the rows."""
        return self.agent.executor

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Observe the step that led here, learn from it, and choose the next actions."""
        obs = TensorDict(
            {k: tensordict.get(STEP_KEYS.get(k, k)) for k in self.obs_keys},
            batch_size=tensordict.batch_size,
        )
        if self._started:
            action = self.agent.step(obs)
            if self.on_batch is not None:
                self.on_batch(self.agent.batch, self.agent.ctx)
        else:
            action = self.agent.start(obs)
            self._started = True
        tensordict.set("action", action)
        return tensordict


def collect(
    env: BatchedEnv,
    policy: HierarchicalPolicy,
    until: Callable[[], bool],
    steps_per_batch: int = 64,
    max_seconds: float | None = None,
    on_iteration: Callable[[float], None] | None = None,
) -> dict[str, float]:
    """Drive ``policy`` over ``env`` with a TorchRL ``Collector`` until ``until()`` holds.

    Args:
        env: the domain (wrapped here in ``AutoResetTorchRLEnv``).
        policy: the hierarchical policy (learns as it acts).
        until: checked after every collected batch.
        steps_per_batch: batched env steps per collector iteration.
        max_seconds: also stop after this much wall-clock time.
        on_iteration: called after every iteration with the seconds so far.

    Returns:
        ``{"seconds", "env_steps", "env_steps_per_second"}``; ``env_steps`` counts every row of
        every batched step (auto-reset steps included), as the trainer does.
    """
    torchrl_env = AutoResetTorchRLEnv(env)
    collector = Collector(
        torchrl_env,
        policy,
        frames_per_batch=steps_per_batch * env.batch_size,
        total_frames=-1,
        trust_policy=True,
        use_buffers=False,  # with buffers the collector calls the policy once to probe its outputs
    )
    start = time.perf_counter()
    frames = 0
    try:
        for data in collector:
            frames += data.numel()
            seconds = time.perf_counter() - start
            if on_iteration is not None:
                on_iteration(seconds)
            if until() or (max_seconds is not None and seconds >= max_seconds):
                break
    finally:
        collector.shutdown()
    seconds = time.perf_counter() - start
    return {
        "seconds": seconds,
        "env_steps": frames,
        "env_steps_per_second": frames / max(seconds, 1e-9),
    }
