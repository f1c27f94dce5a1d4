"""Taxi with fuel (Dietterich 1998; Section 5.2.1): the MAXQ hierarchy with a Refuel subtask.

Task graph (Dietterich's taxi graph, ``agents.taxi``, plus Refuel)::

    Root ─┬─ Get ────┬─ Navigate(t) ── North, South, East, West     t bound to the passenger
          │          └─ Pickup
          ├─ Put ────┬─ Navigate(t)                                 t bound to the destination
          │          └─ Putdown
          └─ Refuel ─┬─ Navigate(F)
                     └─ Fillup

State abstractions (ours where the text is silent; fuel matters only where refuelling is
decided):

=============  ============================================  ======
node           relevant variables                            states
=============  ============================================  ======
Root           passenger location, destination, fuel          260
Get            taxi location, passenger location              125
Put            taxi location, destination                     100
Refuel         taxi location                                  25
Navigate(t)    taxi location (t in R, G, Y, B, F)             25
N/S/E/W        none                                           1
Pickup         taxi location, passenger location              125
Putdown        taxi location, destination                     100
Fillup         taxi location                                  25
=============  ============================================  ======

Refuel ends with a full tank (so it is unavailable when the tank is full). Navigate ignores the
fuel: a move that runs the tank dry ends the episode inside whatever subtask is running, and only
the root (which sees the fuel) can avoid it. The Root does not see the taxi's location, so its
refuelling rule is a function of passenger, destination and fuel: a recursively optimal policy
under these abstractions, which is what all hierarchical learners here can reach.

Algorithms (Figure 5.3): ``hpgrl`` (Algorithm 3, one softmax parameter per (state, child) at
every subtask), ``maxq-q`` and flat ``q`` over the 6,500 states.
"""

from __future__ import annotations

from agents.taxi import (
    PESSIMISTIC_INIT,
    Navigate,
    epsilon_first_third,
    flat_graph,
    get_and_put,
    taxi_primitives,
)
from envs.taxi_fuel import CAPACITY, FUEL_STATION, N_ACTIONS, N_FUEL, N_STATES, TaxiFuelEnv
from hrl_torch.common.config import Make
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner, SMDPQLearner
from hrl_torch.learners.pg import HPGRLLearner, PGConfig
from hrl_torch.modules.exploration import Greedy
from hrl_torch.runs.domain import AlgoSpec, DomainSpec
from hrl_torch.training.config import TrainConfig

FUEL_LOC = FUEL_STATION[0] * 5 + FUEL_STATION[1]


class NavigateToFuel(Navigate):
    """Navigate(F): drive to the fuel station; abstraction: taxi location."""

    def __init__(self) -> None:
        super().__init__(0)
        self.name = "Navigate_F"
        self.target_loc.fill_(FUEL_LOC)


def taxi_fuel_hierarchy(root: Subtask | None = None) -> TaskGraph:
    """Dietterich's taxi graph with Refuel (see the module docstring).

    ``root``: another Root over ``Get``, ``Put`` and ``Refuel`` (another abstraction).
    """
    navs = [Navigate(t) for t in range(4)]
    if root is None:
        root = Subtask(
            "Root",
            ["Get", "Put", "Refuel"],
            n_states=5 * 4 * N_FUEL,
            abstract=lambda o: (o["passenger"] * 4 + o["destination"]) * N_FUEL + o["fuel"],
        )
    get, put = get_and_put([n.name for n in navs])
    refuel = Subtask(
        "Refuel",
        ["Navigate_F", "Fillup"],
        n_states=25,
        abstract=lambda o: o["taxi_loc"],
        terminated=lambda o: o["fuel"] == CAPACITY,
    )
    prims = [*taxi_primitives(), Primitive("Fillup", 6, 25, lambda o: o["taxi_loc"])]
    nodes = [root, get, put, refuel, *navs, NavigateToFuel(), *prims]
    return TaskGraph("Root", nodes, n_actions=N_ACTIONS)


def flat_fuel_graph() -> TaskGraph:
    """Flat Q-learning over the 6,500 states and 7 actions."""
    return flat_graph(N_STATES, N_ACTIONS)


def make_env(seeds, envs_per_learner: int, backend: str = "torch") -> TaxiFuelEnv:
    """Taxi-fuel for ``seeds`` (200-step limit)."""
    if backend != "torch":
        raise ValueError(f"unknown backend {backend!r}")
    return TaxiFuelEnv(seeds, envs_per_learner)


#: HPGRL's step size (ours; the text gives none). The 256 rows of a learner add their updates;
#: 0.02 and 0.05 plateaued far below 0.005 (docs/reproduction.md).
HPGRL_ALPHA = 0.005


#: Algorithm 3 at every subtask: one softmax parameter per (abstract state, child)
HPGRL_PG = PGConfig(alpha=HPGRL_ALPHA, trace_len=200, online=True)  # (the default before 0.2.x)


DOMAIN = DomainSpec(
    name="taxi-fuel-earlier",
    description="taxi with fuel, the reading before Section 5.2.1's (kept for comparison)",
    make_env=make_env,
    algos={
        "hpgrl": AlgoSpec(
            make_graph=taxi_fuel_hierarchy,
            learner=Make(HPGRLLearner),
            pg=HPGRL_PG,
            exploration=Make(Greedy),  # unused: PG nodes sample
            train=TrainConfig(steps=3_000_000, eval_every=20_000, success_key="!out_of_fuel"),
            envs_per_learner=256,
            description="HPGRL (Algorithm 3) with tabular softmax policies at every subtask",
        ),
        "maxq-q": AlgoSpec(
            make_graph=taxi_fuel_hierarchy,
            learner=Make(MaxQLearner, alpha=0.5, gamma=1.0, init=PESSIMISTIC_INIT),
            exploration=epsilon_first_third,
            train=TrainConfig(steps=1_000_000, eval_every=10_000, success_key="!out_of_fuel"),
            envs_per_learner=256,
            description="MAXQ-Q (Dietterich 2000) on the taxi-fuel graph",
        ),
        "q": AlgoSpec(
            make_graph=flat_fuel_graph,
            learner=Make(SMDPQLearner, alpha=0.5, gamma=1.0, init=PESSIMISTIC_INIT),
            exploration=epsilon_first_third,
            train=TrainConfig(steps=3_000_000, eval_every=20_000, success_key="!out_of_fuel"),
            envs_per_learner=256,
            description="flat Q-learning over the 6,500 states",
        ),
    },
)
