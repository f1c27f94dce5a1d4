"""hrl-torch: hierarchical reinforcement learning in PyTorch.

The names below import on first use (PEP 562), so ``hrl-torch --help`` needs no torch. The
subpackages are layers (docs/design.md); the 0.1 module paths (``hrl_torch.trainer``, ...) still
import, with a DeprecationWarning (``hrl_torch.common.compat``).
"""

from __future__ import annotations

import importlib

from hrl_torch.common import compat

compat.install()

_EXPORTS = {
    "ExecutorConfig": "hrl_torch.execution.executor",
    "HierarchicalExecutor": "hrl_torch.execution.executor",
    "SubtaskTimeoutError": "hrl_torch.execution.executor",
    "GraphError": "hrl_torch.hierarchy.graph",
    "Primitive": "hrl_torch.hierarchy.graph",
    "StepContext": "hrl_torch.hierarchy.graph",
    "Subtask": "hrl_torch.hierarchy.graph",
    "TaskGraph": "hrl_torch.hierarchy.graph",
}
__all__ = sorted(_EXPORTS)
__version__ = "0.2.0"


def __getattr__(name: str):
    if name in _EXPORTS:
        return vars(importlib.import_module(_EXPORTS[name]))[name]
    if name in compat.MOVED:  # ``from hrl_torch import trainer`` of 0.1
        new = f"hrl_torch.{compat.MOVED[name]}"
        compat.warn_moved(f"hrl_torch.{name}", new)
        globals()[name] = module = importlib.import_module(new)  # warned once
        return module
    raise AttributeError(f"module 'hrl_torch' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
