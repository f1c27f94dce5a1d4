"""Checkpoint files: atomic writes, safe loads (``weights_only=True``) and clear errors."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from hrl_torch.sparse_store import pack, unpack

FORMAT = "hrl-torch/checkpoint/2"  # 2: mostly-constant tensors stored sparsely (sparse_store)
READABLE = ("hrl-torch/checkpoint/1", FORMAT)


class CheckpointError(RuntimeError):
    """A checkpoint that is corrupt, of another format, or for a different run setup."""


def save_checkpoint(path: str | Path, state: dict) -> Path:
    """Write ``state`` (tensors, numbers, strings, lists and dicts) atomically to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    try:
        torch.save({"format": FORMAT, **pack(state)}, tmp)
        os.replace(tmp, path)
    finally:  # a failed write leaves the previous checkpoint and no stale .tmp
        tmp.unlink(missing_ok=True)
    return path


def load_checkpoint(path: str | Path) -> dict:
    """Read a checkpoint written by ``save_checkpoint``.

    Raises:
        FileNotFoundError: no file at ``path``.
        CheckpointError: the file is truncated, corrupt, or not an hrl-torch checkpoint.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no checkpoint at {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for damaged zip/pickle data
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        if first.startswith("Weights only load failed"):
            first = "torch.load(weights_only=True) refused it"
        raise CheckpointError(f"{path} is corrupt or not a torch checkpoint ({first})") from err
    if not isinstance(state, dict) or state.get("format") not in READABLE:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(f"{path} is not an {FORMAT} checkpoint (found {found!r})")
    try:
        return unpack(state)
    except (KeyError, TypeError, ValueError, RuntimeError, IndexError, AttributeError) as err:
        raise CheckpointError(f"{path} holds a damaged sparse tensor ({err})") from err
