"""The designer's knowledge per domain: task graphs, abstractions and experiment configs.

Importing ``agents`` registers every domain with ``hrl_torch.runs.registry`` (lazily).
"""

from hrl_torch.runs import registry

registry.register("taxi", "agents.taxi:DOMAIN")
registry.register("small-agv", "agents.small_agv:DOMAIN")
registry.register("agv", "agents.agv:DOMAIN")
registry.register("agv-ct", "agents.agv:DOMAIN_CT")
registry.register("taxi-fuel-earlier", "agents.taxi_fuel:DOMAIN")
registry.register("taxi-fuel", "agents.taxi_fuel_text:DOMAIN")
registry.register("ship-steering", "agents.ship_domain:DOMAIN")
registry.register("ship-steering-earlier", "agents.ship_domain:DOMAIN_EARLIER")
registry.register("four-agv-earlier", "agents.four_agv:DOMAIN")
registry.register("four-agv", "agents.four_agv_text:DOMAIN")
registry.register("trash", "agents.trash:DOMAIN")
registry.register("two-taxi-earlier", "agents.two_taxi:DOMAIN")
registry.register("two-taxi", "agents.two_taxi:DOMAIN_TEXT")
registry.register("two-taxi-station", "agents.two_taxi:DOMAIN_TEXT_STATION")
registry.register("four-rooms", "agents.four_rooms:DOMAIN")
registry.register("key-door", "agents.key_door:DOMAIN")
