"""Layer 7: training one population.

The agent step, trainer, evaluation, collectors, run logs, deferred checks and CUDA-graph replay
(``TrainConfig`` is in ``config``).

The names of the 0.1 module ``hrl_torch.training`` still resolve here with a DeprecationWarning.
"""

from hrl_torch.common.compat import moved_attribute


def __getattr__(name: str):
    return moved_attribute(__name__, name)
