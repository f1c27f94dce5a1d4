"""Key and door (``envs.key_door``): fetch the key, unlock the door, walk to the goal.

Task graph::

    Root ─┬─ GetKey ───┬─ Navigate(k), k = key spots 0..3 ── North, South, East, West
          │            └─ Pickup                           k bound to the key's spot
          ├─ OpenDoor ─┬─ Navigate(U)                      U: the cell west of the door
          │            └─ Unlock
          └─ Navigate(g), g = goals 0, 1                   g bound to the episode's goal

The root's children are available in turn: GetKey while the key lies on its spot, OpenDoor
while it is held, Navigate(g) once the door is open. The navigation subtasks are shared by
every start, key spot and goal (each runs with one door state only, so the cell is all it
needs). State abstractions:

=============  ==========================================  ======
node           relevant variables                          states
=============  ==========================================  ======
Root           key, goal                                   12
GetKey         cell, key spot                              164
OpenDoor       cell                                        41
Navigate(t)    cell (t in K0..K3, U, G0, G1)               41
moves          none (always -1)                            1
Pickup         cell, key                                   246
Unlock         cell, key                                   246
=============  ==========================================  ======
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from agents.gridworlds import gridworld_domain, optimal_eval_return
from envs.key_door import (
    GOALS,
    HELD,
    KEY_SPOTS,
    N_ACTIONS,
    N_CELLS,
    N_GOALS,
    N_KEY,
    PICKUP,
    UNLOCK,
    UNLOCK_CELL,
    USED,
    KeyDoorEnv,
    cell_index,
)
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask

MOVES = ["North", "South", "East", "West"]
KEY_NAV = [f"Navigate_K{k}" for k in range(len(KEY_SPOTS))]
GOAL_NAV = [f"Navigate_G{g}" for g in range(N_GOALS)]


class Navigate(Subtask):
    """Navigate(t): walk to cell ``target``; abstraction: the cell."""

    def __init__(self, name: str, target: tuple[int, int], initiable=None) -> None:
        super().__init__(name, MOVES, n_states=N_CELLS, initiable=initiable)
        self.register_buffer("target", torch.tensor(cell_index(*target)), persistent=False)

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        return obs["cell"]

    def terminated(self, obs: TensorDict) -> torch.Tensor:
        return obs["cell"] == self.target


def _bind_key_spot(obs: TensorDict) -> torch.Tensor:
    """GetKey's ``child_mask``: Navigate(k) only for the key's spot ``k``; Pickup always."""
    spots = torch.arange(len(KEY_SPOTS), device=obs.device)
    nav = obs["key"][:, None] == spots[None, :]
    return torch.cat([nav, torch.ones_like(nav[:, :1])], dim=1)


def _cell_and_key(obs: TensorDict) -> torch.Tensor:
    return obs["cell"] * N_KEY + obs["key"]


def key_door_hierarchy() -> TaskGraph:
    """Root -> GetKey, OpenDoor, Navigate(g) (see the module docstring)."""
    root = Subtask(
        "Root",
        ["GetKey", "OpenDoor", *GOAL_NAV],
        n_states=N_KEY * N_GOALS,
        abstract=lambda o: o["key"] * N_GOALS + o["goal"],
    )
    get_key = Subtask(
        "GetKey",
        [*KEY_NAV, "Pickup"],
        n_states=N_CELLS * len(KEY_SPOTS),
        abstract=lambda o: o["cell"] * len(KEY_SPOTS) + o["key"].clamp_max(len(KEY_SPOTS) - 1),
        terminated=lambda o: o["key"] >= HELD,
        child_mask=_bind_key_spot,
    )
    open_door = Subtask(
        "OpenDoor",
        ["Navigate_U", "Unlock"],
        n_states=N_CELLS,
        abstract=lambda o: o["cell"],
        terminated=lambda o: o["key"] == USED,
        initiable=lambda o: o["key"] == HELD,
    )
    navs = [Navigate(name, spot) for name, spot in zip(KEY_NAV, KEY_SPOTS, strict=True)]
    navs.append(Navigate("Navigate_U", UNLOCK_CELL))
    for g, name in enumerate(GOAL_NAV):
        navs.append(
            Navigate(name, GOALS[g], initiable=lambda o, g=g: (o["key"] == USED) & (o["goal"] == g))
        )
    prims = [
        *(Primitive(name, k) for k, name in enumerate(MOVES)),
        Primitive("Pickup", PICKUP, N_CELLS * N_KEY, _cell_and_key),
        Primitive("Unlock", UNLOCK, N_CELLS * N_KEY, _cell_and_key),
    ]
    graph = TaskGraph("Root", [root, get_key, open_door, *navs, *prims], n_actions=N_ACTIONS)
    return KeyDoorEnv.tabulate(graph)


# ---------------------------------------------------------------------- experiments
OPTIMAL = optimal_eval_return(KeyDoorEnv)
#: near-optimal: within a quarter step per episode of the optimal policy
THRESHOLD = OPTIMAL - 0.25


# The best settings of docs/defaults.md (scripts/defaults_table.py, 100,000 steps, 5 seeds):
# pessimistic initial values (-25, below every completion value) and step size 0.5 for both;
# MAXQ-Q with all-states updating reached the threshold in a median 12,500 steps (5/5), flat Q
# in 42,900 (5/5).
INIT = -25.0


DOMAIN = gridworld_domain(
    "key-door",
    "fetch a key, unlock a door, walk to one of two goals",
    KeyDoorEnv,
    key_door_hierarchy,
    "Root -> GetKey, OpenDoor, Navigate(g)",
    OPTIMAL,
    THRESHOLD,
    maxq_init=INIT,
    q_init=INIT,
)
