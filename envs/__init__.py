"""The dissertation's domains, torch-batched, and their gymnasium registrations.

Importing ``envs`` registers each domain with gymnasium under an ``hrl/`` id (lazily, by import
string: the module is only imported on ``gymnasium.make``).
"""

import gymnasium

_REGISTRATIONS = {
    "hrl/Taxi-v0": "envs.taxi:gymnasium_env",
    "hrl/TaxiFuel-v0": "envs.taxi_fuel:gymnasium_env",
    "hrl/ShipSteering-v0": "envs.ship:gymnasium_env",
    "hrl/SmallAGV-v0": "envs.agv_small:gymnasium_env",
    "hrl/AGV-v0": "envs.agv:gymnasium_env",
    "hrl/AGVContinuous-v0": "envs.agv:gymnasium_env_continuous",
    "hrl/FourRooms-v0": "envs.four_rooms:gymnasium_env",
    "hrl/KeyDoor-v0": "envs.key_door:gymnasium_env",
}


def _register() -> None:
    for env_id, entry in _REGISTRATIONS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(env_id, entry_point=entry)


_register()
