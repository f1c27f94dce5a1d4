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

from agents.taxi import flat_graph
from envs.grid import optimal_values
from envs.key_door import (
    GOALS,
    HELD,
    KEY_SPOTS,
    N_ACTIONS,
    N_CELLS,
    N_GOALS,
    N_KEY,
    N_STATES,
    PICKUP,
    UNLOCK,
    UNLOCK_CELL,
    USED,
    KeyDoorEnv,
    cell_index,
    decode,
    transition_tables,
)
from hrl_torch.executor import ExecutorConfig
from hrl_torch.experiment import AlgoSpec, DomainSpec
from hrl_torch.exploration import EpsilonGreedy, Linear
from hrl_torch.graph import Primitive, Subtask, TaskGraph
from hrl_torch.learners import MaxQLearner, SMDPQLearner
from hrl_torch.trainer import TrainConfig

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


def tabulated(graph: TaskGraph) -> TaskGraph:
    """``graph`` with its context computed once for all 492 states."""
    states = torch.arange(N_STATES)
    graph.tabulate(TensorDict(decode(states), batch_size=[N_STATES]))
    return graph


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
    return tabulated(graph)


# ---------------------------------------------------------------------- experiments
def make_env(seeds, envs_per_learner: int, backend: str = "torch") -> KeyDoorEnv:
    """Key and door for ``seeds`` (200-step limit)."""
    if backend != "torch":
        raise ValueError(f"unknown backend {backend!r}")
    return KeyDoorEnv(seeds, envs_per_learner)


EVAL_SEED = 1_000_003
EVAL_EPISODES = 100


def optimal_eval_return(seed: int = EVAL_SEED, episodes: int = EVAL_EPISODES) -> float:
    """The optimal policy's mean return on the evaluation episodes."""
    value = optimal_values(*transition_tables()[:3])
    return float(value[KeyDoorEnv([seed], episodes).reset()["observation"]].mean())


OPTIMAL = optimal_eval_return()
#: near-optimal: within a quarter step per episode of the optimal policy
THRESHOLD = OPTIMAL - 0.25


def _epsilon(config: TrainConfig) -> EpsilonGreedy:
    return EpsilonGreedy(Linear(1.0, 0.05, config.steps // 3))


# The best settings of docs/defaults.md (scripts/defaults_table.py, 100,000 steps, 5 seeds):
# pessimistic initial values (-25, below every completion value) and step size 0.5 for both;
# MAXQ-Q with all-states updating reached the threshold in a median 12,500 steps (5/5), flat Q
# in 42,900 (5/5).
ALPHA = 0.5
INIT = -25.0
VISITED = 32  # states of a child kept for all-states updating


def _spec(make_graph, make_learner, description: str, **options) -> AlgoSpec:
    steps = 100_000
    return AlgoSpec(
        make_graph=make_graph,
        make_learner=make_learner,
        make_exploration=_epsilon,
        train=TrainConfig(steps=steps, eval_every=steps // 20, threshold=THRESHOLD),
        envs_per_learner=64,
        description=description,
        **options,
    )


DOMAIN = DomainSpec(
    name="key-door",
    description="fetch a key, unlock a door, walk to one of two goals",
    make_env=make_env,
    eval_seed=EVAL_SEED,
    reference={f"optimal {OPTIMAL:.2f}": OPTIMAL, f"threshold {THRESHOLD:.2f}": THRESHOLD},
    algos={
        "maxq-q": _spec(
            key_door_hierarchy,
            lambda g, p: MaxQLearner(g, p, ALPHA, 1.0, all_states=True, init=INIT),
            "MAXQ-Q (all-states updating) on Root -> GetKey, OpenDoor, Navigate(g)",
            executor=ExecutorConfig(record_visited=VISITED),
        ),
        "q": _spec(
            lambda: tabulated(flat_graph(N_STATES, N_ACTIONS)),
            lambda g, p: SMDPQLearner(g, p, ALPHA, 1.0, init=INIT),
            "flat Q-learning over the 492 states",
        ),
    },
)
