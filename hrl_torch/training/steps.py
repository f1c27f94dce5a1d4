"""Where a training step's env output and transitions come from: the direct loop or a collector.

Both give ``step() -> (td, transitions)`` for one batched step of the agent on the env and keep
what a checkpoint needs to continue (the direct loop's next actions, the collector's pending
observation); a checkpoint of one cannot continue on the other.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict


class DirectSteps:
    """``env.step`` and ``agent.decide`` in turn (the default loop)."""

    collector = False

    def __init__(self, batch_size: int, agent) -> None:
        self.batch_size, self.agent = batch_size, agent
        self.action: torch.Tensor | None = None

    def step(self, env):
        """The step's output and its transitions on ``env``."""
        if self.action is None:
            self.action = self.agent.start(env.reset())
        td = env.step(self.action)
        self.action, batch = self.agent.decide(td)
        return td, batch

    def close(self) -> None:
        """Nothing runs in the background."""

    def pending(self) -> dict:
        """The observation a collector acts on next (none here)."""
        return {}

    def state_dict(self) -> dict:
        """The next actions and the pending observation, in a checkpoint's keys."""
        action = self.action if self.action is not None else torch.zeros(0)
        return {"action": action, "collector": self.pending()}

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict`` (``state``: the whole checkpoint, for its ``env`` and step)."""
        action = state["action"]
        self.action = None if action.numel() == 0 else action.clone()
        pending = state.get("collector") or {}
        if self.collector != bool(pending) and int(state["step"]) > 0:
            raise ValueError(
                "a checkpoint of the direct loop cannot continue on the collector path, "
                "nor the other way round"
            )
        self.close()
        self._resume(pending)
        if not state["env"]:  # an env that cannot be checkpointed (gymnasium): new episodes
            self.action = None

    def _resume(self, pending: dict) -> None:
        """Continue from the collector's ``pending`` observation (the collector path)."""


class CollectedSteps(DirectSteps):
    """The frames of a TorchRL collector (``hrl_torch.training.collector.CollectorSource``)."""

    collector = True

    def __init__(self, batch_size: int, agent) -> None:
        single_agent_only(agent)
        super().__init__(batch_size, agent)
        self._source = self._steps = self._resume_obs = None  # created at the first step

    def step(self, env):
        """The next frame (a collector over ``env``): the step's output and its transitions."""
        if self._steps is None:
            from hrl_torch.training.collector import CollectorSource  # TorchRL only on this path

            self._source = CollectorSource(env, self.agent, self._resume_obs)
            self._steps = self._source.steps()
            self._resume_obs = None
        return next(self._steps)

    def close(self) -> None:
        """Stop the collector (if one runs)."""
        if self._source is not None:
            self._source.shutdown()
            self._source = self._steps = None

    def pending(self) -> dict:
        """The domain output the agent acts on next."""
        if self._source is not None:
            return self._source.pending.to_dict()
        return {} if self._resume_obs is None else self._resume_obs.to_dict()

    def _resume(self, pending: dict) -> None:
        b = [self.batch_size]
        self._resume_obs = TensorDict(pending, batch_size=b) if pending else None


def single_agent_only(env_or_agent) -> None:
    """The collector path steps single-agent envs only: a clear error for any other.

    ``env_or_agent``: a domain's env, or the agent of one (both say their ``n_agents``).
    """
    n = getattr(env_or_agent, "n_agents", None)
    if n is not None:
        raise ValueError(
            f"the collector path (--collector) is single-agent, and {type(env_or_agent).__name__}"
            f" has {n} agents per row: train it without the collector (docs/collectors.md)"
        )
