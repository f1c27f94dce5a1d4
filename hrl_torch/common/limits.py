"""What this process may still allocate, and the one check every size request goes through.

A size that drives an allocation (env rows, evaluation episodes, learners of a population, a
sparse tensor's declared extent, TensorBoard writer threads) is checked here *before* anything
is allocated, so an oversized request (a typo's ``--envs-per-seed 16777216``, a crafted
checkpoint whose record says ``eval_episodes=10**9``) is one line, not the kernel's
out-of-memory killer or a ``can't allocate`` traceback. The budget is the least of:

- the memory the kernel reports available (``MemAvailable``; the physical memory elsewhere),
- the container's limit (cgroup v2 ``memory.max`` less ``memory.current``; v1 likewise),
- the address space left under ``ulimit -v`` (``RLIMIT_AS`` less the process's ``VmSize``).
"""

from __future__ import annotations

import os
import resource
import threading
from pathlib import Path

#: share of the budget one request may take (the run needs room beyond its largest tensors)
SHARE = 0.8
#: threads one process may start for a run (TensorBoard writers: one per seed)
MAX_THREADS = 1024


class SizeLimitError(ValueError):
    """A request larger than this machine can hold, refused before anything was allocated."""


def _read_int(path: str) -> int | None:
    try:
        text = Path(path).read_text().split()[0]
    except (OSError, IndexError):
        return None
    return int(text) if text.isdigit() else None


def _meminfo(field: str) -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _vm_size() -> int:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def memory_budget() -> tuple[int, str]:
    """``(bytes, where the bound comes from)``: what this process may still allocate."""
    bounds: list[tuple[int, str]] = []
    available = _meminfo("MemAvailable")
    if available is None:
        try:
            available = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            available = None
    if available is not None:
        bounds.append((available, "memory available"))
    for limit, used in (
        ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
        (
            "/sys/fs/cgroup/memory/memory.limit_in_bytes",
            "/sys/fs/cgroup/memory/memory.usage_in_bytes",
        ),
    ):
        cap = _read_int(limit)
        if cap is not None and cap < 2**60:
            bounds.append((max(0, cap - (_read_int(used) or 0)), "the container's memory limit"))
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        bounds.append((max(0, soft - _vm_size()), "address space left under ulimit -v"))
    if not bounds:
        return 2**62, "no known bound"
    return min(bounds)


def gib(n: float) -> str:
    """``n`` bytes as ``'3.2 GiB'`` / ``'512 MiB'``."""
    if n >= 2**30:
        return f"{n / 2**30:,.1f} GiB"
    return f"{n / 2**20:,.0f} MiB" if n >= 2**20 else f"{n / 2**10:,.0f} KiB"


def check_bytes(what: str, need: float, advice: str) -> None:
    """Refuse ``what`` (needing about ``need`` bytes) when it exceeds the budget's share.

    Raises:
        SizeLimitError: ``'{what} needs about 12.0 GiB, more than this process may take
            here (7.5 GiB: 80% of the 9.4 GiB of memory available); {advice}'``.
    """
    budget, source = memory_budget()
    if need > SHARE * budget:
        raise SizeLimitError(
            f"{what} needs about {gib(need)}, more than this process may take here "
            f"({gib(SHARE * budget)}: {SHARE:.0%} of the {gib(budget)} of {source}); {advice}"
        )


def check_threads(what: str, n: int, advice: str) -> None:
    """Refuse starting ``n`` more threads beyond ``MAX_THREADS`` (or the user's process limit)."""
    cap = MAX_THREADS
    soft, _ = resource.getrlimit(resource.RLIMIT_NPROC)
    if soft != resource.RLIM_INFINITY:
        cap = min(cap, max(0, soft - threading.active_count()))
    if n > cap:
        raise SizeLimitError(f"{what} would start {n:,} threads, more than {cap:,}; {advice}")


def tensor_bytes(obj, _seen: set | None = None, _depth: int = 0) -> int:
    """Bytes of the distinct tensor storages reachable from ``obj`` (attributes, containers)."""
    import torch

    seen = set() if _seen is None else _seen
    if _depth > 8 or id(obj) in seen:
        return 0
    seen.add(id(obj))
    if isinstance(obj, torch.Tensor):
        if obj.is_sparse or obj.device.type == "meta":
            return obj.numel() * obj.element_size()
        key = ("storage", obj.untyped_storage().data_ptr())
        if key in seen:
            return 0
        seen.add(key)
        return obj.untyped_storage().nbytes()
    if isinstance(obj, dict):
        return sum(tensor_bytes(v, seen, _depth + 1) for v in obj.values())
    if isinstance(obj, (list, tuple, set)):
        return sum(tensor_bytes(v, seen, _depth + 1) for v in obj)
    if (
        isinstance(obj, (str, bytes, int, float, bool, type(None)))
        or callable(obj)
        and not hasattr(obj, "__dict__")
    ):
        return 0
    if isinstance(obj, torch.nn.Module):
        return sum(tensor_bytes(v, seen, _depth + 1) for v in vars(obj).values())
    if hasattr(obj, "__dict__") and not isinstance(obj, type):
        return sum(tensor_bytes(v, seen, _depth + 1) for v in vars(obj).values())
    items = getattr(obj, "items", None)  # a TensorDict
    if callable(items):
        try:
            return sum(tensor_bytes(v, seen, _depth + 1) for _, v in items())
        except Exception:  # not a mapping after all
            return 0
    return 0
