"""The designer's knowledge per domain: task graphs, abstractions and experiment configs.

Importing ``agents`` registers every domain with ``hrl_torch.registry`` (lazily).
"""

from hrl_torch import registry

registry.register("taxi", "agents.taxi:DOMAIN")
