"""Training fed by ``torchrl.collectors.Collector``: the hierarchical agent as a TorchRL policy.

The acting half of an agent step (``HierarchicalAgent.decide``: context, values, pops, pushes)
runs as a ``TensorDictModuleBase`` policy, ``HierarchicalPolicy``, that changes nothing
learned. The Task-Stack travels in the rollout TensorDict the way a recurrent policy's hidden
state does: the policy reads ``"task_stack"`` and writes ``("next", "task_stack")``, and
TorchRL's ``step_mdp`` carries it to the next step. Each frame carries the step's finished SMDP
transitions under ``"transitions"`` (with the learner's values at ``s'``), and the learner is
updated from the frames: ``CollectorSource`` yields them one batched step at a time, so an
update lands before the next action is chosen, exactly as in the direct loop, and the two paths
learn the same tables from the same seeds (tested). ``Trainer(..., collector=True)`` (CLI:
``--collector``) trains through this path with the same evaluation, logging and checkpoints.

TorchRL resets a finished row itself, and the policy's next input is then the new episode's
first observation: the terminal observation, which the executor needs to end every subtask and
emit its last transitions, would never reach it. So the domain keeps its own next-step
auto-reset (``hrl_torch.env.batched``) and TorchRL sees an env that never ends:
``AutoResetTorchRLEnv`` wraps a ``BatchedEnv`` as an ``EnvBase`` whose ``done`` is always
False; every observation carries the fields of the step that led to it (``step_reward``,
``step_duration``, ``step_terminated``, ``step_truncated``, ``is_init``), so after ``step_mdp``
the policy still sees them.

What of TorchRL works on this path and what does not (docs/collectors.md):

- ``Collector`` (single process): yes, the training path.
- ``ReplayBuffer``: the frames are ordinary TensorDicts and can be stored; the tabular and PG
  updates here are on-policy and in order, so the trainer does not replay them.
- multi-process collectors (``MultiSyncCollector``, ``MultiaSyncCollector``): no. Each worker
  would step its own env copy with its own Task-Stacks, and the policy's values must see the
  learner's tables after every step's update; shipping the tables to workers every step costs
  more than the step. (Subtasks with per-step shaping rewards also read the previous
  observation, which the executor keeps itself, not in the TensorDict.)

TorchRL is imported here and in ``hrl_torch.env.torchrl_env`` only.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.collectors import Collector
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from hrl_torch.common.ops import put
from hrl_torch.env.batched import BatchedEnv
from hrl_torch.env.torchrl_env import init_signature
from hrl_torch.execution.stack import TaskStack
from hrl_torch.training.agent import HierarchicalAgent

#: the step fields of a BatchedEnv output, as observation keys (TorchRL keeps ``reward`` apart)
STEP_KEYS = {
    "reward": "step_reward",
    "duration": "step_duration",
    "terminated": "step_terminated",
    "truncated": "step_truncated",
    "is_init": "is_init",
}
#: key of the Task-Stacks in the rollout TensorDict
STACK = "task_stack"
#: key of a frame's SMDP transitions
TRANSITIONS = "transitions"


def _fields(env: BatchedEnv) -> dict[str, torch.Tensor]:
    """The fields of the domain's step outputs, with their shapes and dtypes (no reset)."""
    b, dev = env.batch_size, env.device
    fields = dict(env.observation())
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


def _observation_spec(env: BatchedEnv, stack: TaskStack) -> Composite:
    """Specs of the domain's fields (sizes and bounds where declared) and of the Task-Stack."""
    b, dev = env.batch_size, env.device
    obs = {}
    for key, value in _fields(env).items():
        name = STEP_KEYS.get(key, key)
        if key in env.observation_sizes:
            obs[name] = Categorical(env.observation_sizes[key], shape=(b,), device=dev)
        elif key in env.observation_bounds:
            low, high = (torch.tensor(x, dtype=torch.float32) for x in env.observation_bounds[key])
            obs[name] = Bounded(low.expand(b, *low.shape), high.expand(b, *high.shape), device=dev)
        else:
            obs[name] = _spec_like(value, dev)
    obs[STACK] = Composite(
        {k: _spec_like(v, dev) for k, v in stack.tensors().items()}, shape=(b,), device=dev
    )
    return Composite(obs, shape=(b,), device=dev)


@init_signature
class AutoResetTorchRLEnv(EnvBase):
    """A ``BatchedEnv`` as a TorchRL env that keeps the domain's next-step auto-reset.

    Every observation field of the domain is an observation key (declared sizes and bounds
    become ``Categorical`` / ``Bounded`` specs, the rest ``Unbounded``), plus ``STEP_KEYS``
    and the Task-Stack (``STACK``, written by the policy). ``done`` is always False: episodes
    end and restart inside the domain. ``last`` is the domain's latest output.

    Args:
        env: the domain.
        stack: the Task-Stacks a reset hands to the policy (empty ones to start).
        resume: a domain output to return from the first reset instead of resetting the
            domain (continuing a run from a checkpoint: the env state is already restored).
    """

    def __init__(self, env: BatchedEnv, stack: TaskStack, resume: TensorDict | None = None) -> None:
        super().__init__(batch_size=torch.Size([env.batch_size]), device=env.device)
        self.env = env
        self.stack = stack
        self.resume = resume
        b, dev = env.batch_size, env.device
        self.observation_spec = _observation_spec(env, stack)
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
        self.last: TensorDict | None = None

    def _wrap(self, out: TensorDict) -> TensorDict:
        self.last = out
        fields = {STEP_KEYS.get(k, k): v for k, v in out.items()}
        fields.update(done=self._false, terminated=self._false, truncated=self._false)
        return TensorDict(fields, batch_size=self.batch_size, device=self.device)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        out = self.resume if self.resume is not None else self.env.reset()
        self.resume = None
        td = self._wrap(out)
        td.set(STACK, TensorDict(self.stack.tensors(), batch_size=self.batch_size))
        return td

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        out = self._wrap(self.env.step(tensordict["action"]))
        out["reward"] = out["step_reward"].unsqueeze(-1)
        return out

    def _set_seed(self, seed: int | None) -> None:
        """Seeds are the domain's (one per learner); TorchRL's seed is ignored."""

    def maybe_reset(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Nothing to reset: ``done`` is always False (the domain resets its own rows).

        (``EnvBase.maybe_reset`` would read ``done.any()`` back at every step.)
        """
        return tensordict


def domain_output(td: TensorDictBase, keys: list[str]) -> TensorDict:
    """The domain's step output (``keys``) from a rollout TensorDict (undo ``STEP_KEYS``)."""
    return TensorDict({k: td.get(STEP_KEYS.get(k, k)) for k in keys}, batch_size=td.batch_size[:1])


class HierarchicalPolicy(TensorDictModuleBase):
    """The agent's acting half as a TorchRL policy (nothing learned changes here).

    It reads the observation and the Task-Stack and writes the action, the next Task-Stack and
    the step's transitions; ``agent.update`` learns from the frames.

    Args:
        agent: the hierarchical agent (its executor's stack is set from the TensorDict).
        obs_keys: the domain's output fields.
    """

    def __init__(self, agent: HierarchicalAgent, obs_keys: list[str]) -> None:
        super().__init__()
        self.agent = agent
        self.obs_keys = obs_keys
        self.in_keys = [STEP_KEYS.get(k, k) for k in obs_keys] + [STACK]
        self.out_keys = ["action", ("next", STACK), TRANSITIONS]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Choose the next actions at the observation of ``tensordict``."""
        b = self.agent.executor.batch_size
        executor = self.agent.executor
        fields = dict(tensordict.get(STACK).items())
        held = executor.stack.tensors()
        if fields.keys() != held.keys() or any(v is not held[k] for k, v in fields.items()):
            executor.stack = TaskStack.from_tensors(fields, b)  # (else: the stack it wrote)
        action, batch = self.agent.decide(domain_output(tensordict, self.obs_keys))
        tensordict.set("action", action)
        stack = TensorDict(executor.stack.tensors(), batch_size=[b], device=tensordict.device)
        tensordict.set(("next", STACK), stack)
        # the transitions are on the frame's device: written without TensorDict's device check
        # (which would rebuild them with ``.to`` every step)
        put(tensordict, TRANSITIONS, batch)
        return tensordict


class _LatestFrame:
    """The collector's direct-write sink: keeps each step's frame by reference.

    The ``Collector`` writes every frame to ``replay_buffer.add`` (its direct-write path)
    instead of stacking the frames of an iteration into new tensors; with one batched step per
    iteration the stack would only copy the frame.
    """

    write_count = 0

    def __init__(self) -> None:
        self.frame: TensorDictBase | None = None

    def add(self, frame: TensorDictBase) -> None:
        """Keep ``frame`` (the collector's rollout TensorDict of one step)."""
        self.frame = frame
        self.write_count += frame.numel()


class CollectorSource:
    """One batched step at a time from a TorchRL ``Collector`` driving ``agent`` over ``env``.

    ``steps()`` yields ``(domain output, transitions)`` per step, like ``env.step`` followed
    by ``agent.decide``; the first frame of a new run (the start at the reset observations, no
    transitions) is consumed inside. Between two yields the caller updates the learner.

    Args:
        env: the domain (wrapped in ``AutoResetTorchRLEnv``).
        agent: the training agent.
        resume: the domain output the agent has not acted on yet (from a checkpoint);
            ``None`` starts a new run.
    """

    def __init__(
        self, env: BatchedEnv, agent: HierarchicalAgent, resume: TensorDict | None = None
    ) -> None:
        self.agent = agent
        self.keys = list(_fields(env))
        if resume is None:
            agent.executor.reset()
        self.torchrl_env = AutoResetTorchRLEnv(env, agent.executor.stack, resume)
        self.policy = HierarchicalPolicy(agent, self.keys)
        self.fresh = resume is None
        self.sink = _LatestFrame()
        self.collector = Collector(
            self.torchrl_env,
            self.policy,
            frames_per_batch=env.batch_size,
            total_frames=-1,
            device=env.device,  # policy, env and frames on one device: no per-step copy
            trust_policy=True,
            use_buffers=False,  # with buffers the collector calls the policy once to probe it
            track_traj_ids=False,
            replay_buffer=self.sink,
            extend_buffer=False,
        )
        self._iter: Iterator | None = None

    @property
    def pending(self) -> TensorDict | None:
        """The domain output the agent will act on next (what a checkpoint keeps)."""
        return self.torchrl_env.last

    def steps(self) -> Iterator[tuple[TensorDict, TensorDict]]:
        """``(domain output, transitions)`` of every further batched step."""
        frames = iter(self.collector)
        if self.fresh:  # the start: the root pushed at the reset observations
            next(frames)
        for _ in frames:  # one batched step, written to the sink
            frame = self.sink.frame
            yield domain_output(frame, self.keys), frame.get(TRANSITIONS)

    def shutdown(self) -> None:
        """Stop the collector."""
        self.collector.shutdown()


def collect(
    env: BatchedEnv,
    agent: HierarchicalAgent,
    until: Callable[[], bool],
    max_seconds: float | None = None,
    on_step: Callable[[float], None] | None = None,
) -> dict[str, float]:
    """Train ``agent`` from a TorchRL ``Collector``'s frames until ``until()`` holds.

    Args:
        env: the domain.
        agent: the training agent (``learn=True``).
        until: checked after every batched step.
        max_seconds: also stop after this much wall-clock time.
        on_step: called with the seconds so far after each update (progress reports).

    Returns:
        ``{"seconds", "env_steps", "env_steps_per_second"}``; ``env_steps`` counts every row of
        every batched step (auto-reset steps included), as the trainer does.
    """
    source = CollectorSource(env, agent)
    start = time.perf_counter()
    frames = 0
    try:
        for _, batch in source.steps():
            agent.update(batch)
            frames += env.batch_size
            seconds = time.perf_counter() - start
            if on_step is not None:
                on_step(seconds)
            if until() or (max_seconds is not None and seconds >= max_seconds):
                break
    finally:
        source.shutdown()
    seconds = time.perf_counter() - start
    return {
        "seconds": seconds,
        "env_steps": frames,
        "env_steps_per_second": frames / max(seconds, 1e-9),
    }
