"""Small tensor helpers for the hot path (CPU advanced indexing is several times slower)."""

from __future__ import annotations

import torch


def lookup(table: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``table[index]`` (rows of ``table``) for any-shaped ``index``.

    A 1-D table is one ``take`` (one op); rows of a larger table one ``index_select``.
    """
    if table.dim() == 1:
        return torch.take(table, index)
    if index.dim() == 1:
        return table.index_select(0, index)
    return table.index_select(0, index.reshape(-1)).view(index.shape + table.shape[1:])


def columns(x: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``x[:, index]`` for ``x [B, N, ...]`` and any-shaped ``index`` into ``N``."""
    if index.dim() == 1:
        return x.index_select(1, index)
    return x.index_select(1, index.reshape(-1)).view(x.shape[0], *index.shape, *x.shape[2:])


def discount(gamma: float, time: torch.Tensor) -> torch.Tensor:
    """``gamma ** time`` in ``time``'s dtype, computed in float64.

    A float32 ``pow`` rounds differently in its vectorised and scalar code paths, so one element
    could get another last bit in a batch of another shape, and a population would no longer
    equal separate runs; through float64 the result agrees.
    """
    return (gamma ** time.double()).to(time.dtype)


def at_rows(x: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``x[b, index[b]]`` for ``x [B, N, *rest]`` and ``index [B]``: ``[B, *rest]``."""
    flat = x.reshape(x.shape[0] * x.shape[1], *x.shape[2:])
    rows = torch.arange(x.shape[0], device=x.device) * x.shape[1] + index
    return flat.index_select(0, rows)
