"""Layer 2: environments.

The batched-env contract (``BatchedEnv``, in ``batched``), its check, the gymnasium, TorchRL and
PettingZoo adapters and the multi-agent env.

The names of the 0.1 module ``hrl_torch.env`` still resolve here with a DeprecationWarning.
"""

from hrl_torch.common.compat import moved_attribute


def __getattr__(name: str):
    return moved_attribute(__name__, name)
