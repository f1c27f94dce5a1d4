"""hrl-torch: hierarchical reinforcement learning in PyTorch."""

from hrl_torch.executor import ExecutorConfig, HierarchicalExecutor, SubtaskTimeoutError
from hrl_torch.graph import GraphError, Primitive, StepContext, Subtask, TaskGraph

__all__ = [
    "ExecutorConfig",
    "GraphError",
    "HierarchicalExecutor",
    "Primitive",
    "StepContext",
    "Subtask",
    "SubtaskTimeoutError",
    "TaskGraph",
]
__version__ = "0.1.0"
