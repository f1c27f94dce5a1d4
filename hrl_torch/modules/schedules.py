"""Schedules: a number as a function of the learner's env-step count, or of an entry's visits.

Step sizes (``alpha``, a PG ``alpha``) and exploration rates (``epsilon``, a temperature) take
them. A schedule is a function of the learner's env-step count, so every learner of a
population sees the same value at the same point of its own training (its numbers may be
per-learner tensors, ``hrl_torch.common.per_learner``: then each learner its own);
``VisitCount`` is a per-entry step size the tables apply (``hrl_torch.modules.tables``).
The learners check a schedule's range with ``hrl_torch.learners.validate``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from hrl_torch.common.per_learner import is_per_learner, per_learner

__all__ = ["Constant", "Exponential", "Linear", "Schedule", "VisitCount", "as_schedule"]


class _PerLearnerFields:
    """A schedule whose numbers may be per-learner tensors ``[P]`` (kept as float64)."""

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if is_per_learner(value):
                object.__setattr__(self, name, per_learner(value))


@dataclass(frozen=True)
class Constant(_PerLearnerFields):
    """A fixed value."""

    value: float

    def __call__(self, step: int) -> float:
        """Value at ``step``."""
        return self.value


@dataclass(frozen=True)
class Linear(_PerLearnerFields):
    """Linear from ``start`` to ``end`` over ``steps`` env steps, then ``end``."""

    start: float
    end: float
    steps: int

    def __call__(self, step: int) -> float:
        """Value at ``step``."""
        if isinstance(step, torch.Tensor):  # (a device clock: the same float64 arithmetic)
            frac = (step.double() / max(self.steps, 1)).clamp(0.0, 1.0)
            return torch.where(frac == 1.0, self.end, self.start + frac * (self.end - self.start))
        frac = min(max(step / max(self.steps, 1), 0.0), 1.0)
        return self.end if frac == 1.0 else self.start + frac * (self.end - self.start)


@dataclass(frozen=True)
class Exponential(_PerLearnerFields):
    """``start * decay ** (step // every)``, never below ``minimum``.

    With per-learner values, equal to the numbers' schedule up to rounding (torch's ``pow``).
    """

    start: float
    decay: float
    every: int = 1
    minimum: float = 0.0

    def __call__(self, step: int) -> float:
        """Value at ``step``."""
        every = max(self.every, 1)
        if isinstance(step, torch.Tensor):  # (a device clock)
            value = self.start * torch.pow(self.decay, (step // every).double())
        else:
            value = self.start * self.decay ** (step // every)
        if isinstance(value, torch.Tensor):
            if is_per_learner(self.minimum):
                return torch.maximum(self.minimum, value)
            return value.clamp_min(self.minimum)
        if is_per_learner(self.minimum):
            return self.minimum.clamp_min(value)
        return max(self.minimum, value)


@dataclass(frozen=True)
class VisitCount:
    """A per-entry step size from the entry's visits: ``alpha_n = clip(1 / n, low, high)``.

    ``n`` counts the updates of that one table entry, this one included: the clipped harmonic
    step size, Section 6.3's ``alpha_t(i)`` that "should be gradually decreased to zero" (the
    stochastic-approximation conditions hold for ``1 / n``; ``low > 0`` keeps tracking a
    changing target, e.g. other agents' policies, and ``high < 1`` keeps the initial value from
    being overwritten by the first target). A tabular learner given ``alpha=VisitCount(...)``
    keeps a count per entry (its tables' ``visits`` buffer, saved with them). Calling it gives
    itself: the tables apply it (``hrl_torch.modules.tables``).

    Args:
        low: the floor ``alpha_min`` (0: plain ``1 / n``).
        high: the ceiling (1: the first update replaces the initial value).
    """

    low: float = 0.0
    high: float = 1.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.low <= self.high <= 1.0 and self.high > 0.0):
            raise ValueError(
                f"VisitCount needs 0 <= low <= high <= 1 and high > 0, got low={self.low}, "
                f"high={self.high}"
            )

    def __call__(self, step: int) -> VisitCount:
        """The same at every step (the visits, not the clock, set the size)."""
        return self

    def keep(self, before: torch.Tensor, hits: torch.Tensor) -> torch.Tensor:
        """``prod_{n = k+1}^{k+m} (1 - alpha_n)``: what ``m`` updates after ``k`` keep of ``W``.

        ``before`` (``k``) and ``hits`` (``m``): float tensors of one shape. The product in
        closed form: ``(1-high)^(visits at the ceiling) * (harmonic part, telescoping to
        first / last) * (1-low)^(visits at the floor)``, so ``m`` same-step updates of one entry
        move it exactly as ``m`` successive ones toward their mean would.
        """
        ceiling = math.floor(1.0 / self.high + 1e-9)  # n <= ceiling: 1/n >= high
        floor = math.floor(1.0 / self.low + 1e-9) if self.low > 0 else math.inf  # n > floor: low
        after = before + hits
        at_high = (after.clamp_max(ceiling) - before).clamp_min(0.0)
        start = before.clamp_min(ceiling)
        end = after.clamp_max(floor) if math.isfinite(floor) else after
        harmonic = torch.where(end > start, start / end.clamp_min(1.0), torch.ones_like(end))
        at_low = (after - before.clamp_min(floor)).clamp_min(0.0) if self.low > 0 else 0.0
        keep = torch.pow(1.0 - self.high, at_high) * harmonic
        return keep * (1.0 - self.low) ** at_low if self.low > 0 else keep


Schedule = Constant | Linear | Exponential | VisitCount


def as_schedule(value: float | torch.Tensor | Schedule) -> Schedule:
    """Wrap a plain number (or a per-learner tensor ``[P]``) as a constant schedule."""
    if is_per_learner(value):
        return Constant(value)
    return Constant(float(value)) if isinstance(value, int | float) else value
