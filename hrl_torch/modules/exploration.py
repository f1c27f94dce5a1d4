"""Exploration over masked action values: greedy, epsilon-greedy and Boltzmann.

Each strategy maps action values ``q [B, A]``, an availability mask ``[B, A]`` and a block of
uniforms ``u [B, A + 1]`` to the chosen child ``[B]`` and a flag ``[B]`` saying whether that
choice is greedy (the flag the average-reward learners use to update their gains only after
non-random actions). Taking pre-drawn uniforms keeps the random stream of a row independent of
how many other rows needed a decision.
The rates may be schedules (``hrl_torch.modules.schedules``: functions of the learner's
env-step count, the same module the learners' step sizes use); ``TriggeredEpsilon``
(Section 5.3's hybrid) is a per-learner epsilon that starts decaying when a domain's monitor
says so.
"""

from __future__ import annotations

import math
import warnings

import torch
from torch import nn

from hrl_torch.common.config import Budget, Make
from hrl_torch.common.devices import move_attributes
from hrl_torch.common.ops import argmax_last
from hrl_torch.common.per_learner import at_learners, holds_per_learner, is_per_learner
from hrl_torch.modules import schedules as _schedules

_TIE_NOISE = 1e-6  # random tie-breaking among equal values (tables start equal)


def masked_argmax(q: torch.Tensor, available: torch.Tensor) -> torch.Tensor:
    """Index of the largest available value per row (``q [..., A]`` -> ``[...]``)."""
    return argmax_last(q.masked_fill(~available, -math.inf))


def uniform_choice(available: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Uniform pick among available entries: the available entry with the largest ``u``.

    ``u [..., A]`` independent uniforms in ``[0, 1)`` (ties have probability 0).
    """
    return argmax_last(u.masked_fill(~available, -1.0))


def uniforms_needed(n_children: int) -> int:
    """Width of the uniform block every strategy's ``select`` takes: one per child and one."""
    return n_children + 1


class Greedy:
    """Always the best available child (random among exact ties).

    Like every strategy: ``q [..., A]``, ``available [..., A]``, uniforms ``u [..., A + 1]``
    (any leading dimensions) and the rows' learners ``[B]`` (optional: per-learner values
    need them) give ``(choice [...], greedy [...])``.
    """

    def select(
        self,
        q: torch.Tensor,
        available: torch.Tensor,
        u: torch.Tensor,
        step: int,
        learner: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(choice, greedy)`` (``learner [B]``: the rows' learners, unused here)."""
        choice = masked_argmax(q + u[..., : q.shape[-1]] * _TIE_NOISE, available)
        return choice, torch.ones_like(choice, dtype=torch.bool)


class EpsilonGreedy:
    """With probability ``epsilon(step)`` a uniformly random available child, else greedy.

    The random child is the available one with the largest of the row's per-child uniforms,
    the same numbers that break the greedy choice's ties (only one of the two is used). A
    per-learner epsilon needs the rows' learners (``select``'s ``learner [B]``).
    """

    def __init__(self, epsilon: float | _schedules.Schedule) -> None:
        self.epsilon = _schedules.as_schedule(epsilon)
        for name in ("value", "start", "end"):  # a probability at every step
            v = getattr(self.epsilon, name, None)
            if v is None or isinstance(v, bool) or not isinstance(v, int | float | torch.Tensor):
                continue
            low, high = (float(v.min()), float(v.max())) if torch.is_tensor(v) else (v, v)
            if not 0.0 <= low <= high <= 1.0:  # (NaN fails too)
                shown = v if not torch.is_tensor(v) else f"[{low}, {high}]"
                where = "epsilon" if name == "value" else f"epsilon.{name}"
                raise ValueError(f"EpsilonGreedy: {where} must be in [0, 1], got {shown}")

    def select(
        self,
        q: torch.Tensor,
        available: torch.Tensor,
        u: torch.Tensor,
        step: int,
        learner: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(choice, greedy)``; a random pick that equals the greedy one counts."""
        a = q.shape[-1]
        per_child, blocked = u[..., :a], ~available
        greedy_choice = argmax_last((q + per_child * _TIE_NOISE).masked_fill(blocked, -math.inf))
        random_choice = argmax_last(per_child.masked_fill(blocked, -1.0))
        explore = u[..., a] < _at_rows(self.epsilon(step), learner, u[..., a])
        choice = torch.where(explore, random_choice, greedy_choice)
        return choice, choice == greedy_choice


class Boltzmann:
    """Softmax over available children with temperature ``temperature(step)``."""

    def __init__(self, temperature: float | _schedules.Schedule) -> None:
        self.temperature = _schedules.as_schedule(temperature)

    def select(
        self,
        q: torch.Tensor,
        available: torch.Tensor,
        u: torch.Tensor,
        step: int,
        learner: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(choice, greedy)`` sampled by inverse CDF."""
        temperature = self.temperature(step)
        if is_per_learner(temperature):
            temp = _at_rows(temperature.clamp_min(1e-8), learner, q[..., 0])[..., None]
        elif isinstance(temperature, torch.Tensor):  # (a device clock's value)
            temp = temperature.clamp_min(1e-8)
        else:
            temp = max(temperature, 1e-8)
        logits = (q / temp).masked_fill(~available, -math.inf)
        probs = torch.softmax(logits, dim=-1)
        pick = u[..., q.shape[-1], None]
        choice = (probs.cumsum(-1) <= pick).sum(-1).clamp_max(q.shape[-1] - 1)
        best = masked_argmax(q, available)
        choice = torch.where(available.gather(-1, choice[..., None]).squeeze(-1), choice, best)
        return choice, choice == best


Exploration = Greedy | EpsilonGreedy | Boltzmann


def has_per_learner_values(exploration) -> bool:
    """Whether ``exploration``'s schedule has a per-learner value (its choices read learners)."""
    schedule = vars(exploration).get("epsilon", vars(exploration).get("temperature"))
    return holds_per_learner(schedule)


def on_device(exploration, device: torch.device):
    """``exploration`` with its per-learner values moved to ``device`` (in place)."""
    if has_per_learner_values(exploration):
        move_attributes(exploration, lambda t: t.to(device))
    return exploration


def _at_rows(value, learner: torch.Tensor | None, like: torch.Tensor):
    """A schedule's value at the rows (``at_learners``); per-learner values need ``learner``."""
    if is_per_learner(value) and learner is None:
        raise ValueError("a per-learner exploration value needs the rows' learners (learner=)")
    return at_learners(value, learner, like)


class TriggeredEpsilon(nn.Module):
    """Per-learner epsilon: ``start`` until a trigger, then ``start / factor ** (n // every)``.

    ``n`` counts the learner's episodes since its trigger fired (Section 5.3: 0.1, 1.01, 50).

    Args:
        n_learners: population size ``P``.
        start: initial epsilon.
        factor: divisor per ``every`` episodes after the trigger.
        every: episodes per division.
    """

    def __init__(
        self, n_learners: int, start: float = 0.1, factor: float = 1.01, every: int = 50
    ) -> None:
        super().__init__()
        self.start, self.factor, self.every = float(start), float(factor), int(every)
        self.register_buffer("episodes", torch.zeros(n_learners, dtype=torch.long))
        self.register_buffer("fired_at", torch.full((n_learners,), -1, dtype=torch.long))

    def observe(self, episodes_ended: torch.Tensor, trigger: torch.Tensor) -> None:
        """Count finished episodes ``[P]``; learners whose ``trigger [P]`` holds start decaying."""
        self.episodes += episodes_ended.long()
        fire = trigger & (self.fired_at < 0)
        self.fired_at = torch.where(fire, self.episodes, self.fired_at)

    def values(self) -> torch.Tensor:
        """Epsilon per learner ``[P]``."""
        since = (self.episodes - self.fired_at).clamp_min(0) // self.every
        decay = self.factor ** since.double()
        eps = torch.where(
            self.fired_at >= 0, self.start / decay, torch.full_like(decay, self.start)
        )
        return eps.float()


def linear_epsilon(start: float, end: float, share) -> Make:
    """Epsilon-greedy, epsilon linear from ``start`` to ``end`` over ``share`` of the budget.

    As data (``AlgoSpec.exploration``): fields ``epsilon.start``, ``epsilon.end`` and
    ``epsilon.steps.fraction``; ``share`` e.g. ``Fraction(1, 3)``.
    """
    schedule = Make(_schedules.Linear, start=start, end=end, steps=Budget(share))
    return Make(EpsilonGreedy, epsilon=schedule)


#: the schedules' old home (0.2.0): they live in ``hrl_torch.modules.schedules`` from 0.2.1 on
_MOVED_TO_SCHEDULES = frozenset(_schedules.__all__)


def __getattr__(name: str):
    """0.2.0's ``exploration.Linear`` (and the other schedules), with a DeprecationWarning."""
    if name in _MOVED_TO_SCHEDULES:
        warnings.warn(
            f"hrl_torch.modules.exploration.{name} moved to hrl_torch.modules.schedules.{name}; "
            "the old name goes in 0.3.0",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(_schedules, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
