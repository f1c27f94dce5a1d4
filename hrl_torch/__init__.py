"""hrl-torch: hierarchical reinforcement learning in PyTorch.

The names below import on first use (PEP 562), so ``hrl-torch --help`` needs no torch.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "ExecutorConfig": "hrl_torch.executor",
    "HierarchicalExecutor": "hrl_torch.executor",
    "SubtaskTimeoutError": "hrl_torch.executor",
    "GraphError": "hrl_torch.graph",
    "Primitive": "hrl_torch.graph",
    "StepContext": "hrl_torch.graph",
    "Subtask": "hrl_torch.graph",
    "TaskGraph": "hrl_torch.graph",
}
__all__ = sorted(_EXPORTS)
__version__ = "0.1.0"


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'hrl_torch' has no attribute {name!r}")
    return vars(importlib.import_module(_EXPORTS[name]))[name]


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
