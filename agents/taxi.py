"""Dietterich's taxi hierarchy (MAXQ, 2000) and the flat graph for Q-learning.

Task graph::

    Root ─┬─ Get ─┬─ Navigate(t) ── North, South, East, West      t bound to the passenger
          │       └─ Pickup
          └─ Put ─┬─ Navigate(t)                                  t bound to the destination
                  └─ Putdown

``Navigate(t)`` is one subtask per station ``t`` (its parameter), shared by Get and Put; each
parent's ``child_mask`` binds ``t``. State abstractions (Dietterich's, Section 5):

=============  ==========================================  ======
node           relevant variables                          states
=============  ==========================================  ======
Root           passenger location, destination             20
Get            taxi location, passenger location           125
Put            taxi location, destination                  100
Navigate(t)    taxi location                               25
N/S/E/W        none (always -1: leaf irrelevance)          1
Pickup         taxi location, passenger location           125
Putdown        taxi location, destination                  100
=============  ==========================================  ======
"""

from __future__ import annotations

from fractions import Fraction

import torch
from tensordict import TensorDict

from envs.taxi import N_ACTIONS, STATIONS, TaxiEnv, decode
from hrl_torch.common.config import Make
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners.neural_maxq import NeuralMaxQLearner
from hrl_torch.modules.exploration import linear_epsilon
from hrl_torch.runs.algorithms import Tasks
from hrl_torch.runs.domain import AlgoSpec, DomainSpec
from hrl_torch.training.config import TrainConfig

IN_TAXI = 4
STATION_NAMES = "RGYB"
_STATION_LOC = torch.tensor([r * 5 + c for r, c in STATIONS])


class Navigate(Subtask):
    """Navigate(t): drive to station ``t``; abstraction: taxi location."""

    def __init__(self, target: int) -> None:
        super().__init__(
            f"Navigate_{STATION_NAMES[target]}", ["North", "South", "East", "West"], n_states=25
        )
        self.target = target
        self.register_buffer("target_loc", _STATION_LOC[target].clone(), persistent=False)

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        return obs["taxi_loc"]

    def terminated(self, obs: TensorDict) -> torch.Tensor:
        return obs["taxi_loc"] == self.target_loc


def bind_child_mask(obs_key: str):
    """``child_mask`` for [Navigate_R..B, X]: allow Navigate(t) only for t = ``obs[obs_key]``."""

    def mask(obs: TensorDict) -> torch.Tensor:
        nav = obs[obs_key][:, None] == torch.arange(4, device=obs.device)[None, :]
        return torch.cat([nav, torch.ones_like(nav[:, :1])], dim=1)

    return mask


def get_and_put(nav_names: list[str]) -> tuple[Subtask, Subtask]:
    """Get and Put with Dietterich's abstractions (shared with ``agents.taxi_fuel``)."""
    get = Subtask(
        "Get",
        [*nav_names, "Pickup"],
        n_states=125,
        abstract=lambda o: o["taxi_loc"] * 5 + o["passenger"],
        terminated=lambda o: o["passenger"] == IN_TAXI,
        child_mask=bind_child_mask("passenger"),
    )
    put = Subtask(
        "Put",
        [*nav_names, "Putdown"],
        n_states=100,
        abstract=lambda o: o["taxi_loc"] * 4 + o["destination"],
        terminated=lambda o: o["passenger"] != IN_TAXI,
        child_mask=bind_child_mask("destination"),
    )
    return get, put


def taxi_primitives() -> list[Primitive]:
    """The six taxi actions; Pickup and Putdown with the abstractions of Get and Put."""
    return [
        Primitive("South", 0),
        Primitive("North", 1),
        Primitive("East", 2),
        Primitive("West", 3),
        Primitive("Pickup", 4, 125, lambda o: o["taxi_loc"] * 5 + o["passenger"]),
        Primitive("Putdown", 5, 100, lambda o: o["taxi_loc"] * 4 + o["destination"]),
    ]


def taxi_hierarchy() -> TaskGraph:
    """Dietterich's MAXQ graph for taxi with his state abstractions."""
    navs = [Navigate(t) for t in range(4)]
    root = Subtask(
        "Root",
        ["Get", "Put"],
        n_states=20,
        abstract=lambda o: o["passenger"] * 4 + o["destination"],
    )
    get, put = get_and_put([n.name for n in navs])
    graph = TaskGraph("Root", [root, get, put, *navs, *taxi_primitives()], n_actions=N_ACTIONS)
    return tabulated(graph)


def tabulated(graph: TaskGraph) -> TaskGraph:
    """``graph`` with its context computed once for all 500 states (a lookup per step).

    Every predicate of the taxi graphs reads the state alone.
    """
    return TaxiEnv.tabulate(graph)


def flat_graph(n_states: int = 500, n_actions: int = N_ACTIONS) -> TaskGraph:
    """One root over the primitive actions, abstraction = the full state (flat Q-learning)."""
    names = [f"a{k}" for k in range(n_actions)]
    root = Subtask("Root", names, n_states=n_states, abstract=lambda o: o["observation"])
    return TaskGraph("Root", [root, *(Primitive(n, k) for k, n in enumerate(names))], n_actions)


# ---------------------------------------------------------------------- experiments
def make_env(seeds, envs_per_learner: int, backend: str = "torch"):
    """Taxi for ``seeds``: the batched env, or gymnasium's own ``Taxi-v4`` through the adapter."""
    if backend == "torch":
        return TaxiEnv(seeds, envs_per_learner)
    if backend == "gymnasium":
        import gymnasium

        from hrl_torch.env.adapters import GymnasiumBatchEnv

        return GymnasiumBatchEnv(
            lambda: gymnasium.make("Taxi-v4"), seeds, envs_per_learner, decode=decode
        )
    raise ValueError(f"unknown backend {backend!r}")


#: Epsilon-greedy from 1 to 0.05 over the first third of the budget: taxi's recipe, also used
#: by taxi-fuel-earlier, the gridworlds and the toy-text envs
epsilon_first_third = linear_epsilon(1.0, 0.05, Fraction(1, 3))


# Pessimistic initial values (below every true completion value): estimates then rise toward
# their targets and a wall-bump's completion, whose target is its own state's value, cannot
# overtake the best move. Zero (optimistic) initial values make greedy policies relapse into
# wall-bumping loops inside Navigate (docs/design.md, "Initial values and greedy loops").
PESSIMISTIC_INIT = -20.0


DOMAIN = DomainSpec(
    name="taxi",
    description="Dietterich's taxi (gymnasium Taxi-v4 dynamics)",
    make_env=make_env,
    backends=("torch", "gymnasium"),
    reference={"optimal expected return 7.93": 7.93, "threshold 7.5": 7.5},
    # every registered tabular algorithm (maxq-q, smdp-q, q, a plugin's ...) with these settings
    tasks=Tasks(
        graphs={"hierarchy": taxi_hierarchy, "flat": lambda: tabulated(flat_graph())},
        offers=frozenset({"tabular", "single-agent", "episodic"}),
        exploration=epsilon_first_third,
        train=TrainConfig(steps=60_000, eval_every=2_048, threshold=7.5),
        envs_per_learner=256,
        learner={"init": PESSIMISTIC_INIT},
        per_algorithm={
            "maxq-q": {"description": "MAXQ-Q (Dietterich 2000) on the MAXQ task graph"},
            "smdp-q": {
                "description": "SMDP Q-learning at every subtask (HSMQ) on the MAXQ task graph"
            },
            "q": {
                "train": TrainConfig(steps=200_000, eval_every=4_096, threshold=7.5),
                "description": "flat Q-learning over the 500 states",
            },
        },
    ),
    algos={  # (not a registered family: tuned here, docs/neural-heads.md)
        "maxq-q-mlp": AlgoSpec(
            make_graph=taxi_hierarchy,
            # (measured in docs/neural-heads.md: 8 Adam steps of 0.002 per env step learn
            # within the budget; 4 of 0.01 and 1 of 0.01 diverged into wall-bump loops)
            learner=Make(
                NeuralMaxQLearner,
                alpha=0.5,
                gamma=1.0,
                lr=0.002,
                hidden=64,
                encoding="onehot",
                init=PESSIMISTIC_INIT,
                updates=8,
            ),
            exploration=epsilon_first_third,
            train=TrainConfig(steps=60_000, eval_every=2_048, threshold=7.5),
            envs_per_learner=256,
            description="MAXQ-Q with MLP completions (one-hot abstract states), trained by Adam",
        ),
    },
)
