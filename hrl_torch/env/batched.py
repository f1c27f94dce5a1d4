"""Batched environments: the interface the executor drives, and a base class for torch envs.

A ``BatchedEnv`` steps ``B = P * E`` independent episodes at once (``E`` envs for each of ``P``
learners) and returns a TensorDict with the observation fields plus

- ``reward`` ``[B]`` float: reward of the step (in continuous time: lump reward plus rate x time),
- ``duration`` ``[B]`` float: time the step took (1 in discrete time),
- ``terminated`` / ``truncated`` ``[B]`` bool: the episode ended / hit its time limit,
- ``is_init`` ``[B]`` bool: the row was reset instead of stepped (next-step auto-reset).

Next-step auto-reset keeps every step fixed-shape: a row that ended at step ``t`` is reset at
step ``t + 1`` (its action is ignored, its reward is 0), so the executor sees the terminal
observation for its updates and the initial observation one step later.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch
from tensordict import TensorDict
from torch import nn

from hrl_torch.common.devices import (
    DeferredCheck,
    apply_to_tensors,
    attributes_of,
    defined_at,
    holds_tensor,
    move_attributes,
    same_device,
)
from hrl_torch.common.rng import BatchRNG


class BatchedEnv:
    """Base class for torch-batched domains with next-step auto-reset.

    Subclasses implement ``_reset_rows(mask)`` (re-draw the state of rows where ``mask``),
    ``_step_all(action) -> (reward, duration, terminated)`` (advance every row) and
    ``_observe() -> dict`` (observation fields of every row), and list their state tensors in
    ``state_keys`` for checkpoints.

    What a subclass can use: ``self.batch_size`` (``B = len(seeds) * E`` rows, learner ``p``'s
    rows are ``p * E .. p * E + E - 1``), ``self.device`` and ``self.rng`` (a ``BatchRNG``, one
    random stream per row). Draw random numbers for *every* row at every call (``rng.uniform``,
    ``rng.integers``, then use them where needed), never only for the rows that need them: a
    row's stream must not depend on the other rows, or a population would differ from
    separate runs.

    Args:
        seeds: one seed per learner.
        envs_per_learner: ``E``.
        n_actions: size of the discrete action space (``None`` for continuous actions).
        max_episode_steps: time limit (truncation), ``None`` for no limit.
        device: where the state lives.
    """

    state_keys: tuple[str, ...] = ()
    #: agents per env row (``None``: a single-agent env; ``hrl_torch.env.multiagent_env`` sets it)
    n_agents: int | None = None
    #: discrete observation fields and their number of values (shape ``[B]``, long)
    observation_sizes: dict[str, int] = {}
    #: continuous observation fields: ``(low, high)`` per field (shape ``[B, *shape]``, float)
    observation_bounds: dict[str, tuple[list[float], list[float]]] = {}
    #: ``(low, high)`` of a continuous action ``[B, *shape]`` (``n_actions`` is then ``None``)
    action_bounds: tuple[list[float], list[float]] | None = None
    #: the action check, when deferred (``defer_checks``)
    deferred_action: DeferredCheck | None = None

    def __init__(
        self,
        seeds: Sequence[int],
        envs_per_learner: int,
        n_actions: int | None,
        max_episode_steps: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        self.device = torch.device(device)
        self.seeds = [int(s) for s in seeds]
        self.envs_per_learner = envs_per_learner
        self.n_learners = len(self.seeds)
        self.batch_size = self.n_learners * envs_per_learner
        self.n_actions = n_actions
        self.max_episode_steps = max_episode_steps
        self.rng = BatchRNG(self.seeds, envs_per_learner, stream="env", device=self.device)
        self.elapsed = torch.zeros(self.batch_size, dtype=torch.long, device=self.device)
        self.done = torch.zeros(self.batch_size, dtype=torch.bool, device=self.device)

    # -- subclass hooks
    def _reset_rows(self, mask: torch.Tensor) -> None:
        raise NotImplementedError

    def _step_all(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def _observe(self) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    # -- the hooks as adapters call them (TorchRL, PettingZoo, collectors): no counters, no checks
    def observation(self) -> dict[str, torch.Tensor]:
        """Every row's observation fields now (``_observe``)."""
        return self._observe()

    def reset_rows(self, mask: torch.Tensor) -> None:
        """New episodes in the rows ``mask`` (``_reset_rows``; ``elapsed`` and ``done`` kept)."""
        self._reset_rows(mask)

    def step_all(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One step of every row (``_step_all``): ``(reward, duration, terminated)`` ``[B]``."""
        return self._step_all(action)

    # -- public API
    def reset(self) -> TensorDict:
        """Start a new episode in every row and return the observations."""
        every = torch.ones(self.batch_size, dtype=torch.bool, device=self.device)
        self._reset_rows(every)
        self.elapsed = torch.zeros_like(self.elapsed)
        self.done = torch.zeros_like(self.done)
        zero = torch.zeros(self.batch_size, device=self.device)
        return self._output(zero, zero.clone(), self.done, self.done.clone(), every)

    def step(self, action: torch.Tensor) -> TensorDict:
        """Advance every row one primitive step (rows that ended last step are reset instead)."""
        action = torch.as_tensor(action, device=self.device)
        if self.n_actions is not None:
            action = self._checked(action)
        was_done = self.done  # (never written in place: a returned ``is_init`` stays valid)
        reward, duration, terminated = self._step_all(action)
        on_env_device(self, "_step_all", reward=reward, duration=duration, terminated=terminated)
        fresh = ~was_done
        elapsed = self.elapsed + 1
        if self.max_episode_steps is None:
            truncated = torch.zeros_like(terminated)
        else:
            truncated = (elapsed >= self.max_episode_steps) & fresh
        self._reset_rows(was_done)
        self.elapsed = elapsed.masked_fill(was_done, 0)
        zero = self._zero()
        reward = torch.where(was_done, zero, reward.float())
        duration = torch.where(was_done, zero, duration.float())
        terminated = terminated & fresh
        self.done = terminated | truncated
        return self._output(reward, duration, terminated, truncated, was_done)

    def _checked(self, action: torch.Tensor) -> torch.Tensor:
        """``action`` checked: a ``[B]`` batch inside the action space.

        Rows whose episode ended may hold anything (they are reset; their action is ignored).
        """
        if action.shape != (self.batch_size,):
            raise ValueError(
                f"action must have shape [{self.batch_size}], got {tuple(action.shape)}"
            )
        if action.is_floating_point() or action.dtype == torch.bool or action.is_complex():
            raise ValueError(
                f"actions of {type(self).__name__} are integer indices into [0, "
                f"{self.n_actions}) (torch.long), got {action.dtype}"
            )
        if self.deferred_action is not None:  # (no read: raised at the trainer's next read)
            inside = action.clamp(0, self.n_actions - 1)  # (a bad row's action: ignored)
            self.deferred_action.record((inside != action) & ~self.done, action=action)
            return inside
        low, high = torch.stack(torch.aminmax(action)).tolist()
        if low >= 0 and high < self.n_actions:
            return action
        bad = (action < 0) | (action >= self.n_actions)
        if bool((bad & ~self.done).any()):
            row = int((bad & ~self.done).nonzero()[0])
            raise ValueError(
                f"action {int(action[row])} outside the action space [0, {self.n_actions}) "
                f"(env row {row})"
            )
        return torch.where(bad, torch.zeros_like(action), action)

    def defer_checks(self) -> DeferredCheck:
        """Check actions without a device read from now on (``hrl_torch.training.deferred``)."""
        n = self.n_actions

        def describe(row: int, saved: dict) -> Exception:
            action = int(saved["action"][row])
            return ValueError(f"action {action} outside the action space [0, {n}) (env row {row})")

        self.deferred_action = DeferredCheck(describe)
        return self.deferred_action

    def _zero(self) -> torch.Tensor:
        """A 0-d zero on the env's device (kept)."""
        zero = self.__dict__.get("_zero_scalar")
        if zero is None or zero.device != self.device:
            zero = self._zero_scalar = torch.zeros((), device=self.device)
        return zero

    def _output(self, reward, duration, terminated, truncated, is_init) -> TensorDict:
        fields = self._observe()
        on_env_device(self, "_observe", **fields)
        fields.update(
            reward=reward,
            duration=duration,
            terminated=terminated,
            truncated=truncated,
            is_init=is_init,
        )
        return TensorDict._new_unsafe(fields, batch_size=self._batch_shape(), device=self.device)

    def _batch_shape(self) -> torch.Size:
        return torch.Size([self.batch_size])

    def to(self, device: torch.device | str) -> BatchedEnv:
        """Move every tensor of the env (state, tables, random streams) to ``device``."""
        device = torch.device(device)
        if device == self.device:
            return self
        move = lambda t: t.to(device)  # noqa: E731
        for name, value in vars(self).items():
            if name != "rng" and holds_tensor(value):
                setattr(self, name, apply_to_tensors(move, value))
            if _plain_helper(value):  # (a helper object's tensors: a distribution's support)
                move_attributes(value, move)
        self.rng = self.rng.to(device)
        self.device = device
        return self

    #: ``subset`` keeps every row's behaviour: all per-row state is in ``state_keys`` (and
    #: ``elapsed``, ``done``, ``rng``). A class sets True once that holds (greedy evaluation
    #: then stops stepping finished rows); ``tests/test_eval_compaction.py`` checks it
    subset_safe: bool = False

    def subset(self, rows: torch.Tensor) -> BatchedEnv:
        """An env of the rows ``rows`` only, each in its current state with its own stream.

        What greedy evaluation uses to stop stepping finished rows. ``n_learners`` and
        ``envs_per_learner`` lose their meaning in the copy (its rows are not whole learners).
        """
        sub = copy.copy(self)
        for key in self.state_keys:
            setattr(sub, key, vars(self)[key][rows])
        sub.elapsed, sub.done = self.elapsed[rows], self.done[rows]
        sub.rng = self.rng.subset(rows)
        sub.batch_size = int(rows.shape[0])
        return sub

    def learner_of_row(self) -> torch.Tensor:
        """Learner index of every row: ``[B]``."""
        return torch.arange(self.batch_size, device=self.device) // self.envs_per_learner

    def state_dict(self) -> dict:
        """Every tensor and counter needed to continue exactly."""
        state = {k: vars(self)[k].clone() for k in self.state_keys}
        state.update(
            elapsed=self.elapsed.clone(), done=self.done.clone(), rng=self.rng.state_dict()
        )
        state["seeds"] = list(self.seeds)  # whose streams these are (checked on load)
        return state

    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict``; shapes and seeds must match this env."""
        if "seeds" in state and list(state["seeds"]) != list(self.seeds):
            raise ValueError(
                f"env state of seeds {list(state['seeds'])}, but this env runs seeds "
                f"{list(self.seeds)}: the tables would continue under other seeds' labels"
            )
        for k in (*self.state_keys, "elapsed", "done"):
            value = state[k]
            current = vars(self)[k]
            if value.shape != current.shape:
                raise ValueError(
                    f"env state {k!r}: shape {tuple(value.shape)} != {tuple(current.shape)}"
                )
            setattr(self, k, value.to(self.device).clone())
        self.rng.load_state_dict(state["rng"])


def _plain_helper(value) -> bool:
    """A plain object an env keeps (not a module, env, random stream or type)."""
    owned = type(value).__module__.split(".")[0] in ("envs", "agents", "hrl_torch")
    return (
        owned
        and attributes_of(value) is not None
        and not isinstance(value, (type, nn.Module, BatchRNG, BatchedEnv))
    )


def on_env_device(env, method: str, **fields) -> None:
    """Each of ``fields`` (what ``env.method`` returned) is a tensor on ``env.device``.

    A tensor an env makes on the CPU would otherwise fail later, deep inside the step (or copy
    to the GPU at every step); the check compares devices and reads no data.
    """
    for key, value in fields.items():
        if not torch.is_tensor(value) or value.device == env.device:  # (others: check_env's)
            continue
        if not same_device(value.device, env.device):
            raise ValueError(
                f"{type(env).__name__}.{method} ({defined_at(getattr(env, method))}) returned "
                f"{key!r} on {value.device}, the env is on {env.device}: make it from the env's "
                f"tensors (torch.where, torch.ones_like(...), device=self.device; module-level "
                f"tables via devices.constant_on)"
            )
