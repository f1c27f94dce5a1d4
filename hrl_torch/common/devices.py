"""Moving a module's plain tensor attributes with its buffers (docs/design.md, "Any device").

``nn.Module.to`` moves parameters and buffers only. Tensors a module keeps as plain attributes
(lists of index tensors, scratch space) would stay on the CPU; a module with
``MovesTensorAttrs`` moves them too, so that nothing of a run is left behind on another device.
"""

from __future__ import annotations

import dataclasses as dc
import types
from collections.abc import Callable

import torch


def apply_to_tensors(fn, value):
    """``value`` with ``fn`` applied to every tensor in it (tensors, lists, tuples, dicts).

    A frozen dataclass holding tensors (a schedule of per-learner values) is copied with its
    fields moved.
    """
    if isinstance(value, torch.Tensor):
        return fn(value)
    if _frozen_dataclass(value):
        fields = {f.name: apply_to_tensors(fn, vars(value)[f.name]) for f in dc.fields(value)}
        return dc.replace(value, **fields)
    if isinstance(value, list):
        return [apply_to_tensors(fn, v) for v in value]
    if isinstance(value, tuple):
        return tuple(apply_to_tensors(fn, v) for v in value)
    if isinstance(value, dict):
        return {k: apply_to_tensors(fn, v) for k, v in value.items()}
    return value


class MovesTensorAttrs:
    """Mixin for an ``nn.Module``: ``.to()`` and friends move its plain tensor attributes too.

    Every attribute that is a tensor, or a list, tuple or dict holding one, moves with the
    buffers, except those named in ``_kept_on_host`` (host copies construction reads).
    """

    _kept_on_host: tuple[str, ...] = ()

    def _apply(self, fn, recurse=True):
        out = super()._apply(fn, recurse)
        for name, value in list(vars(self).items()):
            if name not in _MODULE_DICTS and name not in self._kept_on_host:
                if holds_tensor(value):
                    setattr(self, name, apply_to_tensors(fn, value))
        return out


#: ``nn.Module``'s own dictionaries (parameters, buffers, submodules, hooks)
_MODULE_DICTS = frozenset(vars(torch.nn.Module()))


def holds_tensor(value, depth: int = 0) -> bool:
    """Whether ``value`` is a tensor or a list, tuple or dict holding one."""
    if isinstance(value, torch.Tensor):
        return True
    if depth < 3 and isinstance(value, (list, tuple)):
        return any(holds_tensor(v, depth + 1) for v in value)
    if depth < 3 and isinstance(value, dict):
        return any(holds_tensor(v, depth + 1) for v in value.values())
    if depth < 3 and _frozen_dataclass(value):
        return any(holds_tensor(v, depth + 1) for v in vars(value).values())
    return False


def _frozen_dataclass(value) -> bool:
    """Whether ``value`` is an instance of a frozen dataclass (a schedule, say)."""
    return (
        dc.is_dataclass(value) and not isinstance(value, type) and value.__dataclass_params__.frozen
    )


_NOT_HELPERS = (types.FunctionType, types.MethodType, type, torch.nn.Module)


def attributes_of(obj) -> dict | None:
    """``vars(obj)``, or ``None`` for an object without instance attributes (a number, a tuple)."""
    try:
        return vars(obj)
    except TypeError:
        return None


def move_attributes(obj, fn, depth: int = 0) -> None:
    """Apply ``fn`` to the tensors among ``obj``'s attributes, in place (a plain helper object).

    A plain object held as an attribute (a rule wrapping another rule) is moved the same way,
    two levels deep; functions, classes and modules are left alone.
    """
    for key, inner in vars(obj).items():
        if holds_tensor(inner):
            setattr(obj, key, apply_to_tensors(fn, inner))
        elif depth < 2 and attributes_of(inner) is not None and not isinstance(inner, _NOT_HELPERS):
            move_attributes(inner, fn, depth + 1)


class KeepsHostCopies(MovesTensorAttrs):
    """``MovesTensorAttrs`` that keeps the CPU buffers a move replaces (``host(name)``).

    Construction reads structure (sizes, index sets) from them, never from the device: on
    ``meta`` there is nothing to read, on a GPU each read would synchronise.
    """

    _kept_on_host = ("_host",)

    def _apply(self, fn, recurse=True):
        host = vars(self).get("_host", {})
        host.update({n: b for n, b in self.named_buffers() if b.device.type == "cpu"})
        out = super()._apply(fn, recurse)
        self._host = host
        return out

    def host(self, name: str) -> torch.Tensor:
        """Buffer ``name`` on the CPU, as built (construction reads it, not the device's)."""
        buf = self.get_buffer(name)
        return buf if buf.device.type == "cpu" else self._host[name]


class DeferredCheck:
    """A per-step check latched on the device; ``error()`` builds its exception afterwards.

    ``record(bad [B], **fields)`` keeps, per row, the fields of the first step the row failed
    (one ``where`` per field and an in-place or: no read, fixed shapes).

    Args:
        describe: ``describe(row, saved)`` -> the exception of the lowest failing row, given
            the fields ``saved`` (host tensors) of its first failing step.
        on_read: called after each read of the flags (a check can refresh what it knows).
    """

    def __init__(self, describe: Callable[[int, dict], Exception], on_read=None) -> None:
        self.describe, self.on_read = describe, on_read
        self.bad: torch.Tensor | None = None  # [B] bool: rows that failed so far
        self.saved: dict[str, torch.Tensor] = {}
        self._views: dict[int, torch.Tensor] = {}  # ``bad`` viewed for a field's rank

    def takes(self, bad: torch.Tensor) -> bool:
        """Whether ``bad`` has the rows of the latched ones (another batch: check at once)."""
        return self.bad is None or self.bad.shape[0] == bad.shape[0]

    def record(self, bad: torch.Tensor, **fields: torch.Tensor) -> None:
        """Latch the rows ``bad [B]`` and, for rows failing for the first time, ``fields``."""
        if self.bad is None:
            self.bad = bad.clone()
            self.saved = {k: v.clone() for k, v in fields.items()}
            return
        for key, value in fields.items():
            kept = self._views.get(value.dim())
            if kept is None:  # (a view of ``bad``, updated in place: made once)
                kept = self._views[value.dim()] = self.bad.view(-1, *[1] * (value.dim() - 1))
            self.saved[key] = torch.where(kept, self.saved[key], value)
        self.bad.logical_or_(bad)

    def error(self) -> Exception | None:
        """The latched failure's exception, or ``None`` (reads the device)."""
        failed = self.bad is not None and bool(self.bad.any())
        if self.on_read is not None:
            self.on_read()
        if not failed:
            return None
        row = int(self.bad.nonzero()[0])
        return self.describe(row, {k: v.cpu() for k, v in self.saved.items()})


#: ``None``: updates compact the rows they touch on the CPU (``nonzero``: cheap there) and keep
#: static shapes elsewhere (no host read); ``True``: static shapes on every device (what the
#: counting test checks on the CPU); ``False``: compaction everywhere
STATIC_SHAPES: bool | None = None


def static_shapes(device: torch.device) -> bool:
    """Whether a training step on ``device`` keeps static shapes (``STATIC_SHAPES``)."""
    return device.type != "cpu" if STATIC_SHAPES is None else STATIC_SHAPES


def same_device(a: torch.device, b: torch.device) -> bool:
    """Whether ``a`` and ``b`` name one device (``cuda`` and ``cuda:0`` do).

    An index counts only when both have one.
    """
    if a.type != b.type:
        return False
    return a.index is None or b.index is None or a.index == b.index


def defined_at(fn) -> str:
    """``file:line`` where the function (or bound method, or callable object) ``fn`` is defined."""
    code = getattr(getattr(fn, "__func__", fn), "__code__", None)
    if code is None:  # (a callable object: its class's method)
        code = getattr(vars(type(fn)).get("__call__"), "__code__", None)
    if code is None:
        return "?"
    return f"{'/'.join(code.co_filename.split('/')[-2:])}:{code.co_firstlineno}"


_CONSTANTS: dict[tuple[int, torch.device], tuple[torch.Tensor, torch.Tensor]] = {}


def constant_on(table: torch.Tensor, device: torch.device | str) -> torch.Tensor:
    """A module-level constant ``table`` on ``device``, copied there once and then reused.

    ``TABLE.to(device)`` inside a step copies host memory at every call: a synchronising
    copy on a GPU, which a CUDA-graph capture refuses. The first call (in an eager warm-up
    step) makes the copy; later calls return it. Only for tensors that are never changed.
    """
    device = torch.device(device)
    if table.device == device:
        return table
    key = (id(table), device)
    held = _CONSTANTS.get(key)
    if held is None or held[0] is not table:  # (a new tensor at a reused id)
        held = _CONSTANTS[key] = (table, table.to(device))
    return held[1]


def from_host(data, dtype: torch.dtype, device: torch.device | str) -> torch.Tensor:
    """``torch.tensor(data)`` on ``device`` with a copy that does not synchronise.

    On a GPU the data goes through pinned memory and a non-blocking copy (PyTorch's pinned
    allocator keeps the buffer until the copy has run); on the CPU it is made in place.
    Not inside a replayed step (a graph would copy the same buffer again): there the numbers
    must come from the device (``BatchRNG.count_on_device``).
    """
    device = torch.device(device)
    host = torch.tensor(data, dtype=dtype)
    if device.type == "cpu":
        return host
    if device.type == "cuda":
        host = host.pin_memory()
    return host.to(device, non_blocking=True)


def check_device(text) -> str:
    """``text`` if it names a torch device this machine has (``meta`` too), else ``ValueError``.

    ``'cuda:7'`` on a machine with one GPU is refused here, not by an ``AssertionError`` when
    the first tensor moves.
    """
    if not isinstance(text, str | torch.device):
        raise ValueError(f"device must be a torch device name, got {text!r}")
    try:
        dev = torch.device(text)
    except (RuntimeError, ValueError) as err:
        raise ValueError(f"not a torch device: {text!r}") from err
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"{text}: no CUDA device on this machine")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(
                f"{text}: this machine has {torch.cuda.device_count()} CUDA device(s) "
                f"(cuda:0 to cuda:{torch.cuda.device_count() - 1})"
            )
    if dev.type == "mps" and not torch.backends.mps.is_available():
        raise ValueError(f"{text}: this torch build has no usable MPS device")
    return str(text)
