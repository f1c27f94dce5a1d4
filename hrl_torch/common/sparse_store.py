"""Mostly-constant tensors stored as (fill, positions, values): small checkpoints, exact bits.

A learner's tables start at one initial value and a run visits few of their entries (the
four-AGV cooperative root has 186,624 joint states x 9 children per agent and seed), so a
checkpoint of dense tables is mostly that one value. ``pack`` replaces every tensor of at least
``MIN_NUMEL`` elements whose entries equal one value at least ``1 - MAX_SHARE`` of the time by
a small dict; ``unpack`` restores it bit for bit (floats are compared as their bit patterns, so
``-0.0`` and every NaN come back as they were).
"""

from __future__ import annotations

import torch

MARK = "__hrl_torch_sparse__"
MIN_NUMEL = 4096
MAX_SHARE = 0.25  # beyond this share of other values, dense is smaller (12 bytes each vs 4)
SAMPLE = 1024  # entries sampled to pick the fill value
_BITS = {8: torch.int64, 4: torch.int32, 2: torch.int16, 1: torch.uint8}
_DTYPES = {  # the dtypes a packed tensor may name (a checkpoint names no other attribute)
    str(d).removeprefix("torch."): d
    for d in (torch.float64, torch.float32, torch.float16, torch.bfloat16, torch.int64,
              torch.int32, torch.int16, torch.int8, torch.uint8, torch.bool)
}  # fmt: skip


def _as_bits(t: torch.Tensor) -> torch.Tensor:
    return t.contiguous().view(_BITS[t.element_size()]).reshape(-1)


def pack_tensor(t: torch.Tensor) -> torch.Tensor | dict:
    """``t`` (alone: a view into a larger bank is copied out), or its sparse form if smaller."""
    if t.untyped_storage().nbytes() > t.numel() * t.element_size():
        t = t.clone()  # torch.save writes a view's whole storage
    if t.numel() < MIN_NUMEL or t.is_complex() or t.element_size() not in _BITS:
        return t
    bits = _as_bits(t.detach().cpu())
    step = max(1, bits.numel() // SAMPLE)
    fill = bits[::step].mode().values  # the most common value of an even sample
    where = (bits != fill).nonzero().squeeze(1)
    if where.numel() > MAX_SHARE * bits.numel():
        return t
    return {
        MARK: list(t.shape),
        "dtype": str(t.dtype).removeprefix("torch."),
        "fill": fill,
        "index": where,
        "values": bits[where],
    }


def unpack_tensor(packed: dict) -> torch.Tensor:
    """The tensor ``pack_tensor`` stored, bit for bit."""
    dtype = _DTYPES[packed["dtype"]]
    bits = packed["fill"].expand(torch.Size(packed[MARK]).numel()).clone()
    bits[packed["index"]] = packed["values"]
    return bits.view(dtype).reshape(packed[MARK])


def pack(state):
    """``state`` (nested dicts and lists) with its large mostly-constant tensors packed."""
    if isinstance(state, torch.Tensor):
        return pack_tensor(state)
    if isinstance(state, dict):
        return {k: pack(v) for k, v in state.items()}
    if isinstance(state, (list, tuple)):
        return type(state)(pack(v) for v in state)
    return state


def declared_bytes(state) -> int:
    """Bytes the packed tensors in ``state`` declare (their shapes), before any is built."""
    if isinstance(state, dict):
        if MARK in state:
            shape = state[MARK]
            if not isinstance(shape, list) or not all(
                isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape
            ):
                raise ValueError(f"a packed tensor's shape is {str(shape)[:60]}")
            return torch.Size(shape).numel() * _DTYPES[state["dtype"]].itemsize
        return sum(declared_bytes(v) for v in state.values())
    if isinstance(state, list | tuple):
        return sum(declared_bytes(v) for v in state)
    return 0


def unpack(state, check_size: bool = True):
    """The inverse of ``pack``.

    First, unless ``check_size`` is off, the packed tensors' declared sizes are checked
    against what this process may allocate (``hrl_torch.common.limits``): a checkpoint of a
    few KB may declare a table of 2**40 entries.
    """
    if check_size:
        from hrl_torch.common.limits import check_bytes

        check_bytes(
            "the checkpoint's packed tables (their declared shapes)",
            declared_bytes(state),
            "it was not written for this machine, or it was edited",
        )
    if isinstance(state, dict):
        if MARK in state:
            return unpack_tensor(state)
        return {k: unpack(v, False) for k, v in state.items()}
    if isinstance(state, (list, tuple)):
        return type(state)(unpack(v, False) for v in state)
    return state
