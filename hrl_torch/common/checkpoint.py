"""Checkpoints: atomic writes, safe loads (``weights_only=True``) and clear errors.

``Checkpointer`` saves and restores every part of a training run at once.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import torch

from hrl_torch.common.limits import SizeLimitError
from hrl_torch.common.signals import signals_deferred
from hrl_torch.common.sparse_store import pack, unpack

FORMAT = "hrl-torch/checkpoint/2"  # 2: mostly-constant tensors stored sparsely (sparse_store)
READABLE = ("hrl-torch/checkpoint/1", FORMAT)


class CheckpointError(RuntimeError):
    """A checkpoint that is corrupt, of another format, or for a different run setup."""


def save_checkpoint(path: str | Path, state: dict) -> Path:
    """Write ``state`` (tensors, numbers, strings, lists and dicts) atomically to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    packed = {"format": FORMAT, **pack(state)}
    with signals_deferred():  # a signal waits for the write: no stale .tmp, no half file
        try:
            if tmp.is_symlink() or tmp.is_file():  # a link there is removed, not written through
                tmp.unlink()
            torch.save(packed, tmp)
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
    except SizeLimitError as err:
        raise CheckpointError(f"{path}: {err}") from err
    except (KeyError, TypeError, ValueError, RuntimeError, IndexError, AttributeError) as err:
        raise CheckpointError(f"{path} holds a damaged sparse tensor ({err})") from err


@runtime_checkable
class Stateful(Protocol):
    """What a checkpoint saves and restores: ``state_dict`` and ``load_state_dict``."""

    def state_dict(self) -> dict:
        """The part's state (tensors, numbers, strings, lists and dicts)."""
        ...

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``; a ``ValueError`` (or other error) when it does not fit."""
        ...


@dataclass
class StateOf:
    """A ``Stateful`` made of two functions (e.g. a loop's own counters)."""

    state_dict: Callable[[], dict]
    load_state_dict: Callable[[dict], None]


class Checkpointer:
    """A training run's checkpoint: every part's state, restored all or nothing.

    Args:
        parts: ``() -> {name: part}``, each saved under its name (``None``: the run has no
            such part); asked at every save and load, so a part replaced (``trainer.env =
            ...``) is the one saved.
        flat: parts whose keys go at the top level of the state (the loop's counters).
        optional: names a checkpoint may lack (the part then keeps its state).
    """

    def __init__(
        self,
        parts: Callable[[], dict[str, Stateful | None]],
        flat: tuple[Stateful, ...] = (),
        optional: frozenset[str] = frozenset(),
    ) -> None:
        self._parts = parts
        self.flat, self.optional = flat, optional

    @property
    def parts(self) -> dict[str, Stateful]:
        """The named parts now (those that exist)."""
        return {k: v for k, v in self._parts().items() if v is not None}

    def state_dict(self) -> dict:
        """Everything needed to continue the run exactly."""
        state = {k: part.state_dict() for k, part in self.parts.items()}
        for part in self.flat:
            state.update(part.state_dict())
        return state

    def load_state_dict(self, state: dict) -> None:
        """Restore ``state_dict``; on any mismatch nothing changes and ``CheckpointError`` rises.

        A learned tensor holding NaN (a table no update can have written) is such a mismatch.
        """
        for key, value in (state.get("learner") or {}).items():
            if torch.is_tensor(value) and value.is_floating_point() and value.isnan().any():
                raise CheckpointError(f"checkpoint does not fit this run: learner {key} holds NaN")
        backup = copy.deepcopy(self.state_dict())
        try:
            self._apply(state)
        except Exception as err:
            self._apply(backup)
            what = "; ".join(line.strip() for line in str(err).splitlines() if line.strip())
            raise CheckpointError(f"checkpoint does not fit this run: {what}") from err

    def _apply(self, state: dict) -> None:
        for name, part in self.parts.items():
            if name in state or name not in self.optional:
                part.load_state_dict(state[name])
        for part in self.flat:
            part.load_state_dict(state)

    def save(self, path, run: dict | None = None) -> None:
        """Write the checkpoint (and the run's configuration ``run``, if known) to ``path``."""
        state = {"trainer": self.state_dict()}
        if run is not None:
            state["run"] = run
        save_checkpoint(path, state)

    def load(self, path) -> None:
        """Continue from a checkpoint written by ``save``."""
        self.load_state_dict(load_checkpoint(path)["trainer"])
