"""Layer 8: the multi-agent learners of Chapter 6.

Cooperative subtasks and the multi-agent agent (``cooperative``), the sequential broadcast,
communication and the factory.

The names of the 0.1 module ``hrl_torch.multiagent`` still resolve here with a DeprecationWarning.
"""

from hrl_torch.common.compat import moved_attribute


def __getattr__(name: str):
    return moved_attribute(__name__, name)
