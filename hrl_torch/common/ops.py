"""Small tensor helpers for the hot path (CPU advanced indexing is several times slower)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict


def lookup(table: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``table[index]`` (rows of ``table``) for any-shaped ``index``.

    A 1-D table is one ``take`` (one op); rows of a larger table one ``index_select``.
    """
    if table.dim() == 1:
        return torch.take(table, index)
    if index.dim() == 1:
        return table.index_select(0, index)
    return table.index_select(0, index.reshape(-1)).view(index.shape + table.shape[1:])


#: ``take_flat`` gathers with ``index_select`` from this many indices on (on the CPU)
TAKE_BY_SELECT = 2048


def take_flat(table: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``torch.take(table, index)`` for a contiguous ``table`` and indices in ``[0, numel)``.

    On the CPU ``take`` costs about 2.5x an ``index_select`` of the flat table for many
    indices (237 against 91 us for ``[5120, 7, 5]`` indices into 179k entries) and 3 us less
    for a few; from ``TAKE_BY_SELECT`` indices on it is the ``index_select`` (the same
    values). Unlike ``take``, no negative indices.
    """
    if index.numel() < TAKE_BY_SELECT or table.device.type != "cpu" or not table.is_contiguous():
        return torch.take(table, index)
    return table.view(-1).index_select(0, index.reshape(-1)).view(index.shape)


#: ``argmax_last`` switches to ``max(-1).indices`` from this many elements on (on the CPU)
ARGMAX_BY_MAX = 256


def argmax_last(x: torch.Tensor, keepdim: bool = False) -> torch.Tensor:
    """``x.argmax(-1)``: the index of the first maximum along the last dimension.

    NaN counts as the maximum; either route gives the same indices. On the CPU ``argmax`` over
    a small last dimension is slow for many rows (313 us for ``[5120, 4, 5]``, 75 us for
    ``[1000, 7, 5]``); ``max(-1).indices`` is 2.5-3x faster there, but costs a microsecond
    more below ``ARGMAX_BY_MAX`` elements.
    """
    if x.device.type == "cpu" and x.numel() >= ARGMAX_BY_MAX:
        return x.max(-1, keepdim=keepdim).indices
    return x.argmax(-1, keepdim=keepdim)


#: ``columns`` gathers through a transposed copy from this many elements of ``x`` on (CPU)
COLUMNS_TRANSPOSED = 1 << 14


def columns(x: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``x[:, index]`` for ``x [B, N, ...]`` and any-shaped ``index`` into ``N``.

    On the CPU, ``index_select`` along dimension 1 copies element by element (1.1 ms for
    ``[5120, 14]`` bools to ``[5120, 126]``); from ``COLUMNS_TRANSPOSED`` elements on the
    gather goes along dimension 0 of a transposed copy instead (about 20x faster there).
    """
    shape = (x.shape[0], *index.shape, *x.shape[2:])
    if x.device.type == "cpu" and x.numel() >= COLUMNS_TRANSPOSED:
        picked = x.transpose(0, 1).contiguous().index_select(0, index.reshape(-1))
        return picked.transpose(0, 1).contiguous().view(shape)
    if index.dim() == 1:
        return x.index_select(1, index)
    return x.index_select(1, index.reshape(-1)).view(shape)


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


def entries(td: TensorDict) -> dict:
    """A TensorDict's entries as a plain dict, for reading on the hot path (no copy).

    A plain ``TensorDict``'s own dict (do not write into it); other kinds (lazy stacks,
    tensorclasses) are read out. Reading a key this way costs a dict lookup instead of the
    few microseconds of ``td[key]``.
    """
    if type(td) is TensorDict:
        return td._tensordict
    return dict(td.items())


def put(td: TensorDict, key: str, value) -> None:
    """``td[key] = value`` without TensorDict's checks, for the hot path.

    ``value`` must have ``td``'s batch shape (and device): the caller vouches for it.
    """
    if type(td) is TensorDict:
        td._tensordict[key] = value
    else:
        td.set(key, value)


#: ``add_at`` switches to a flat ``index_add_`` from this many values on (on the CPU)
ADD_AT_FLAT = 4096


def add_at(table: torch.Tensor, index: tuple[torch.Tensor, ...], values: torch.Tensor) -> None:
    """``table[index] += values`` with repeated indices summed, in place.

    ``index`` holds one index tensor per dimension of ``table`` (broadcast with ``values``).
    One ``index_put_(accumulate=True)`` for small batches (fewest ops); from
    ``ADD_AT_FLAT`` values on, on the CPU, one flat ``index_add_`` (``index_put_``'s
    accumulation is several times slower per element there).
    """
    if values.numel() < ADD_AT_FLAT or table.device.type != "cpu":
        table.index_put_(index, values, accumulate=True)
        return
    flat = index[-1]
    for k in range(len(index) - 1):
        flat = flat + index[k] * table.stride(k)
    flat, values = torch.broadcast_tensors(flat, values)
    table.view(-1).index_add_(0, flat.reshape(-1), values.reshape(-1))


def below(cut: torch.Tensor) -> torch.Tensor:
    """``[B, S]`` bool: level ``k`` or one above it is cut (a prefix or along dim 1).

    ``cut.cummax(1).values``, but a ``cumsum``: CUDA's scan with indices took 9.5 of 36 ms
    of a taxi step at 10^6 rows on an H200; ``cumsum`` is also 2x faster on the CPU.
    """
    return cut.cumsum(1) > 0


def one_hot_mask(index: torch.Tensor, n: int) -> torch.Tensor:
    """``one_hot(index, n).bool()`` with no host read (``one_hot`` reads the range back).

    An index outside ``[0, n)`` gives an all-False row instead of an error.
    """
    return index[..., None] == torch.arange(n, device=index.device)


def group_of_rows(index: torch.Tensor) -> torch.Tensor:
    """``unique(index, return_inverse=True)[1]`` with fixed shapes and no host read.

    Each row's rank among the distinct values (by sorting: a new group where the sorted
    value changes), what ``unique`` returns as the inverse.
    """
    value, order = index.sort()
    starts = torch.ones_like(value, dtype=torch.long)
    starts[1:] = value[1:] != value[:-1]
    return torch.empty_like(order).scatter_(0, order, starts.cumsum(0) - 1)


@dataclass(frozen=True)
class RowLayout:
    """How a batch's rows are laid out over the learners (read once, on the CPU).

    Attributes:
        distinct: every row is another learner's (no two rows share a table entry).
        blocks: ``P`` when every learner ``0..P-1`` has the same number of rows, else 0.
        order: ``None`` when those rows are already ``P`` blocks in learner order (row ``b`` of
            learner ``b // E``), else ``(order, inverse)`` on the rows' device: the stable
            permutation that makes them so (a multi-agent env's rows interleave the agents'
            table sets) and its inverse. Neural heads batch over the population with them.
    """

    distinct: bool
    blocks: int
    order: tuple[torch.Tensor, torch.Tensor] | None


def row_layout(host_rows: torch.Tensor, device: torch.device | str = "cpu") -> RowLayout:
    """The ``RowLayout`` of the rows ``host_rows [B]`` (each row's learner), read here once."""
    b = host_rows.numel()
    host = host_rows.cpu()
    distinct = host.unique().numel() == b
    p = int(host.max()) + 1 if b else 0
    equal = b > 0 and bool((torch.bincount(host, minlength=p) == b // p).all())
    blocks = p if equal and b % p == 0 else 0
    order = None
    if blocks and not torch.equal(host, torch.arange(b) // (b // p)):
        perm = torch.sort(host, stable=True).indices
        inverse = torch.empty_like(perm).scatter_(0, perm, torch.arange(b))
        order = (perm.to(device), inverse.to(device))
    return RowLayout(distinct, blocks, order)
