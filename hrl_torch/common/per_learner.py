"""Hyperparameters with one value per learner: a grid of configurations as one population.

A step size, an exploration rate or a schedule's end may be a number (every learner's) or a
float64 tensor ``[P]``: learner ``p`` then uses ``value[p]`` (``hrl_torch.runs.population_grid``
trains a grid x seeds this way). A row reads its learner's value where the rule uses it, so
the update rules keep their equations' form.

Bit-for-bit equal to the number: a Python number is a double until it meets a float32 tensor,
where it becomes ``float32(value)``. The per-learner values are therefore kept in float64, the
schedules do their arithmetic on them as Python would on the number, and ``at_learners`` /
``at_entries`` cast to the tables' dtype only where the number would meet them. Give float64
tensors (as ``population_grid`` does): a float32 tensor holds ``float32(value)``, not the
number, and the tables then differ in the last bits.
"""

from __future__ import annotations

import dataclasses

import torch


def is_per_learner(value) -> bool:
    """Whether ``value`` is a per-learner tensor (rather than one number for all)."""
    return isinstance(value, torch.Tensor) and value.dim() > 0


def per_learner(value: torch.Tensor) -> torch.Tensor:
    """``value`` as a float64 vector ``[P]``; ``ValueError`` for another shape or non-floats."""
    if value.dim() != 1 or not (value.is_floating_point() or value.dtype == torch.long):
        raise ValueError(
            f"a per-learner value must be a 1-D float tensor (one value per learner), "
            f"got shape {tuple(value.shape)} and dtype {value.dtype}"
        )
    return value.to(torch.float64)


def _parts(value) -> list:
    """A number or tensor, or a schedule's numbers and tensors (its fields)."""
    if isinstance(value, (int, float, torch.Tensor)):
        return [value]
    return list(vars(value).values()) if dataclasses.is_dataclass(value) else []


def holds_per_learner(value) -> bool:
    """Whether a number or schedule ``value`` has a per-learner tensor in it."""
    return any(map(is_per_learner, _parts(value)))


def check_size(owner: object, name: str, value, n_learners: int) -> None:
    """Each per-learner tensor in ``value`` has one entry per learner (else ``ValueError``)."""
    for part in filter(is_per_learner, _parts(value)):
        if part.shape != (n_learners,):
            raise ValueError(
                f"{type(owner).__name__}: {name} has {tuple(part.shape)} values; a population "
                f"of {n_learners} learners needs one per learner"
            )


def refuse(owner: object, name: str, value) -> None:
    """``ValueError`` when ``value`` is per learner (a rule that reads one number for all)."""
    if holds_per_learner(value):
        raise ValueError(
            f"{type(owner).__name__}: {name} must be one number or schedule for every learner "
            "(per-learner values are read by the tabular learners and epsilon-greedy only)"
        )


def at_learners(value, learner: torch.Tensor, like: torch.Tensor):
    """``value`` at rows of learners ``learner [B]``, to meet ``like [B, ...]`` in an op.

    A number is returned as it is; a tensor ``[P]`` as ``value[learner]`` in ``like``'s dtype,
    shaped ``[B, 1, ...]`` to broadcast with ``like``.
    """
    if not is_per_learner(value):
        return value
    rows = value.to(like.dtype).index_select(0, learner.reshape(-1))
    return rows.view(*learner.shape, *[1] * (like.dim() - learner.dim()))


def at_entries(value, index: torch.Tensor, stride: int, dtype: torch.dtype):
    """``value`` at flat table indices ``index`` of a store holding ``P`` blocks of ``stride``.

    Entry ``i`` is learner ``i // stride``'s; an index past the last block (a sentinel) reads
    the last learner's value. A number is returned as it is.
    """
    if not is_per_learner(value):
        return value
    learner = torch.div(index, stride, rounding_mode="floor").clamp(0, value.shape[0] - 1)
    return value.to(dtype).index_select(0, learner.reshape(-1)).view(index.shape)
