"""The dissertation's domains, torch-batched, and their gymnasium registrations.

Importing ``envs`` registers each domain with gymnasium under an ``hrl/`` id (lazily, by import
string: the module is only imported on ``gymnasium.make``).
"""

import gymnasium

_REGISTRATIONS = {
    "hrl/Taxi-v0": "envs.taxi:gymnasium_env",
}


def _register() -> None:
    for env_id, entry in _REGISTRATIONS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(env_id, entry_point=entry)


_register()
