"""Counting host synchronisations and data-dependent ops (docs/design.md, "Any device").

A step that a CUDA graph can replay (or ``torch.compile`` can trace whole) reads nothing back
to the host and has shapes that do not depend on data. ``HostSyncCounter`` is a
``TorchDispatchMode`` that counts the aten ops breaking either rule while it is active: scalar
reads (``.item()``, ``bool()``, ``int()``, ``float()`` of a tensor all reach
``aten._local_scalar_dense``; ``tolist`` makes one per element), ``nonzero``, ``masked_select``,
boolean-mask indexing (``index`` with a ``bool`` index), ``unique``, ``repeat_interleave``
without an output size, copies from a non-CPU device to the CPU, and copies of host data to a
device (``"to_device"``: ``TABLE.to(device)``, ``torch.tensor(data, device=...)``, a device
tensor indexed with CPU indices), which synchronise on a GPU and which a CUDA-graph capture
refuses. Deterministic, and it needs no GPU: on the CPU (or ``meta``) it counts the same calls a
GPU run would synchronise on.
"""

from __future__ import annotations

import os
import sysconfig
from collections import Counter

import tensordict
import torch
from torch.utils._python_dispatch import TorchDispatchMode

aten = torch.ops.aten

#: ops whose output size (or value on the host) depends on the data
DATA_DEPENDENT = {
    aten._local_scalar_dense.default: "item",
    aten.nonzero.default: "nonzero",
    aten.nonzero_static.default: None,  # (static: fine)
    aten.masked_select.default: "masked_select",
    aten._unique2.default: "unique",
    aten.unique_dim.default: "unique",
    aten.unique_consecutive.default: "unique",
    aten.argwhere.default: "nonzero",
}


#: tensor methods that read the data on the host with no aten op on the CPU
_HOST_READS = ("tolist", "numpy")
#: functions that copy host data to a device with no aten op the mode sees
_MAKERS = ("tensor", "as_tensor")


def _is_bool_index(args) -> bool:
    indices = args[1] if len(args) > 1 else ()
    return any(isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in indices or ())


class HostSyncCounter(TorchDispatchMode):
    """Count host reads and data-dependent ops while active (``counts``: a ``Counter``).

    ``with HostSyncCounter() as c: trainer.train_step()`` then ``c.total`` is the number of
    such ops in the step, ``c.counts`` says which, ``c.where`` (with ``stacks=True``) where.
    """

    def __init__(self, stacks: bool = False) -> None:
        super().__init__()
        self.counts: Counter[str] = Counter()
        self.stacks = stacks
        self.where: Counter[str] = Counter()

    @property
    def total(self) -> int:
        """The number of counted ops."""
        return sum(self.counts.values())

    def _kind(self, func, args, kwargs) -> str | None:
        kind = DATA_DEPENDENT.get(func)
        if kind is not None:
            return kind
        if func in (aten.index.Tensor, aten.index_put.default, aten.index_put_.default):
            if _is_bool_index(args):
                return "bool-index"
            return "to_device" if _host_index(args) else None
        if func is aten.repeat_interleave.Tensor and kwargs.get("output_size") is None:
            return "repeat_interleave"
        if func in (aten._to_copy.default, aten.copy_.default):
            return _device_to_host(func, args, kwargs) or _host_to_device(func, args, kwargs)
        return None

    def __enter__(self):
        # ``tolist`` and ``numpy`` read a CPU tensor without an aten op, ``torch.tensor(data,
        # device=...)`` copies host data to the device without one: count them here
        self._saved = {name: getattr(torch.Tensor, name) for name in _HOST_READS}
        for name, method in self._saved.items():
            setattr(torch.Tensor, name, self._counting(name, method))
        self._makers = {name: getattr(torch, name) for name in _MAKERS}
        for name, make in self._makers.items():
            setattr(torch, name, self._counting_maker(make))
        self._new_tensor = torch.Tensor.new_tensor
        torch.Tensor.new_tensor = self._counting_new_tensor(self._new_tensor)
        return super().__enter__()

    def __exit__(self, *exc):
        for name, method in self._saved.items():
            setattr(torch.Tensor, name, method)
        for name, make in self._makers.items():
            setattr(torch, name, make)
        torch.Tensor.new_tensor = self._new_tensor
        return super().__exit__(*exc)

    def _counting_maker(self, make):
        def counted(data, *args, device=None, **kwargs):
            from_device = isinstance(data, torch.Tensor) and data.device.type != "cpu"
            if device is not None and torch.device(device).type != "cpu" and not from_device:
                self._count("to_device")
            return make(data, *args, device=device, **kwargs)

        return counted

    def _counting_new_tensor(self, new_tensor):
        def counted(tensor, data, *args, **kwargs):
            device = kwargs.get("device") or tensor.device
            if torch.device(device).type != "cpu":
                self._count("to_device")
            return new_tensor(tensor, data, *args, **kwargs)

        return counted

    def _counting(self, name, method):
        def counted(tensor, *args, **kwargs):
            self._count(name)
            return method(tensor, *args, **kwargs)

        return counted

    def _count(self, kind: str) -> None:
        self.counts[kind] += 1
        if self.stacks:
            self.where[f"{kind} {_caller()}"] += 1

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        kind = self._kind(func, args, kwargs)
        if kind is not None:
            self._count(kind)
        return func(*args, **kwargs)


def _device_to_host(func, args, kwargs) -> str | None:
    """A copy from a non-CPU tensor to the CPU (a read back), else ``None``."""
    if func is aten._to_copy.default:
        src, dst = args[0], kwargs.get("device")
        moved = dst is not None and torch.device(dst).type == "cpu"
        return "to_host" if moved and src.device.type != "cpu" else None
    dst, src = args[0], args[1]
    is_read = isinstance(src, torch.Tensor) and src.device.type != "cpu"
    return "to_host" if is_read and dst.device.type == "cpu" else None


def _host_to_device(func, args, kwargs) -> str | None:
    """A copy from the CPU to another device (synchronising on a GPU), else ``None``.

    A non-blocking copy (``devices.from_host``: from pinned memory on a GPU) is not one.
    """
    blocking = not (kwargs.get("non_blocking") or (len(args) > 2 and args[2]))
    if not blocking:
        return None
    if func is aten._to_copy.default:
        src, dst = args[0], kwargs.get("device")
        moved = dst is not None and torch.device(dst).type != "cpu"
        return "to_device" if moved and src.device.type == "cpu" else None
    dst, src = args[0], args[1]
    is_host = isinstance(src, torch.Tensor) and src.device.type == "cpu"
    return "to_device" if is_host and dst.device.type != "cpu" else None


def _host_index(args) -> bool:
    """Whether a device tensor is indexed with CPU index tensors (copied over first)."""
    if args[0].device.type == "cpu":
        return False
    indices = args[1] if len(args) > 1 else ()
    return any(isinstance(i, torch.Tensor) and i.device.type == "cpu" for i in indices or ())


def _caller() -> str:
    """``dir/file:line`` of the innermost frame outside torch that made the op."""
    import traceback

    return place(traceback.extract_stack())


def _folder(module) -> str:
    return os.path.dirname(os.path.abspath(module.__file__)) + os.sep


#: frames inside these are not the code that made an op (``place``): torch, tensordict, the
#: standard library, and the checking code
_LIBRARIES = (_folder(torch), _folder(tensordict))
_STDLIB = sysconfig.get_paths()["stdlib"] + os.sep
_CHECKERS = ("sync_count.py", "devicecheck.py")
_PACKAGES = "-packages" + os.sep  # (site-packages, dist-packages)


def _library(name: str) -> bool:
    """Whether a frame's file is torch's, tensordict's, the standard library's or a checker's."""
    if name.startswith(("<", *_LIBRARIES)) or os.path.basename(name) in _CHECKERS:
        return True
    return name.startswith(_STDLIB) and _PACKAGES not in name


def place(frames) -> str:
    """``dir/file:line`` of the innermost of ``frames`` outside torch and the checking code.

    ``frames``: ``traceback.FrameSummary`` items, outermost first. The frame found is the code
    that made the op: this project's, or a user's own env or subtask. A frame of another
    installed package (under ``site-packages``) is named only when no frame outside one is.
    """
    kept = [f for f in reversed(list(frames)) if not _library(f.filename)]
    own = [f for f in kept if _PACKAGES not in f.filename]
    if not (own or kept):
        return "?"
    frame = (own or kept)[0]
    name = frame.filename.replace("\\", "/")
    return f"{'/'.join(name.split('/')[-2:])}:{frame.lineno}"


def count_train_step(trainer, steps: int = 1, stacks: bool = False) -> HostSyncCounter:
    """The ops of ``steps`` calls of ``trainer.train_step()`` (what the trainer does per step)."""
    with HostSyncCounter(stacks=stacks) as counter:
        for _ in range(steps):
            trainer.train_step()
    return counter
