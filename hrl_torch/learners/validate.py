"""Hyperparameter checks at construction: a clear error instead of tables full of NaN."""

from __future__ import annotations

import math

import torch

from hrl_torch.common.per_learner import refuse
from hrl_torch.modules.schedules import Constant, Exponential, Linear, Schedule, VisitCount


def schedule_values(value: float | Schedule) -> list[float]:
    """The values a number or schedule can take at its ends (what a range check needs).

    Per-learner values (``hrl_torch.common.per_learner``) give every learner's (read at
    construction).
    """
    if isinstance(value, Constant):
        return _numbers(value.value)
    if isinstance(value, VisitCount):  # (checked when made; 1/n itself stays in (0, 1])
        return [value.high]
    if isinstance(value, Linear):
        return _numbers(value.start) + _numbers(value.end)
    if isinstance(value, Exponential):
        if max(_numbers(value.decay)) > 1:
            return [math.inf]
        return _numbers(value.start) + [max(m, 0.0) for m in _numbers(value.minimum)]
    return _numbers(value)


def _numbers(value) -> list[float]:
    """A number, or a tensor's numbers, as floats."""
    if isinstance(value, torch.Tensor):
        return [float(v) for v in value.reshape(-1).tolist()]
    return [float(value)]


def check_range(owner: object, name: str, value, low: float, high: float, open_low: bool) -> None:
    """Raise ``ValueError`` unless every end value of ``value`` lies in the range."""
    for v in schedule_values(value):
        ok = math.isfinite(v) and (v > low if open_low else v >= low) and v <= high
        if not ok:
            bracket = "(" if open_low else "["
            raise ValueError(
                f"{type(owner).__name__}: {name} must be in {bracket}{low:g}, {high:g}], got {v}"
            )


def check_step_size(owner: object, name: str, value, one_for_all: bool = False) -> None:
    """A TD step size: in ``(0, 1]`` (``one_for_all``: not per learner)."""
    check_range(owner, name, value, 0.0, 1.0, open_low=True)
    if one_for_all:
        refuse(owner, name, value)


def check_fraction(owner: object, name: str, value) -> None:
    """A discount or trace decay: in ``[0, 1]``."""
    check_range(owner, name, value, 0.0, 1.0, open_low=False)


def check_positive(owner: object, name: str, value, one_for_all: bool = False) -> None:
    """A gradient step size: finite and ``> 0`` (``one_for_all``: not per learner)."""
    for v in schedule_values(value):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{type(owner).__name__}: {name} must be > 0 and finite, got {v}")
    if one_for_all:
        refuse(owner, name, value)
