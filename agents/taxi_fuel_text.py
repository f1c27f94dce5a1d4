"""Taxi-fuel as Section 5.2.1 sets it (``taxi-fuel``): 8,750 states, average reward per step.

Beside ``taxi-fuel-earlier`` (``agents.taxi_fuel``), three things follow the text:

- the env ``envs.taxi_fuel_text``: the text's 8,750 states, no time limit, Fillup away from F
  is not penalised;
- the root sees the whole state (taxi location, passenger, destination, fuel: the 8,750
  states). The text's hierarchy is Dietterich's (1998) decomposition (footnote 4), and it names
  no state abstraction; a root without the taxi location (``taxi-fuel-earlier``'s 260 states) cannot
  tell how far F and the passenger are, so it cannot decide when to refuel. The nodes below
  the root keep Dietterich's abstractions (the fuel never changes what a shortest route is);
- the measure is the average reward per step over the run (the text's "average reward per
  step"): the training reward per step with exploration (``charts/reward_rate``, what an
  online learner earns) and the greedy policy's reward per step over a run of episodes, one
  after the other (``charts/eval_throughput``; ``hrl_torch.training.continuing``). A reset step has
  no reward and no duration, so an episode's end costs no time.

Algorithms: ``hpgrl`` (Algorithm 3 at every node, one softmax parameter per (state, child)),
``maxq-q`` and flat ``q`` over the 8,750 states, configured as on ``taxi-fuel-earlier`` except
MAXQ-Q's step size and final epsilon (``MAXQ_ALPHA``, ``MAXQ_EXPLORATION``: chosen by ``hrl-torch
sweep`` on this domain, docs/reproduction.md).
"""

from __future__ import annotations

from fractions import Fraction

from agents.taxi import (
    IN_TAXI,
    PESSIMISTIC_INIT,
    Navigate,
    bind_child_mask,
    epsilon_first_third,
    flat_graph,
    taxi_primitives,
)
from agents.taxi_fuel import HPGRL_PG, NavigateToFuel, taxi_fuel_hierarchy
from envs.taxi_fuel_text import CAPACITY, FACTORS, N_STATES, TaxiFuelTextEnv
from hrl_torch.common.config import Make
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner, SMDPQLearner
from hrl_torch.learners.pg import HPGRLLearner
from hrl_torch.modules.exploration import Greedy, linear_epsilon
from hrl_torch.runs.domain import AlgoSpec, DomainSpec
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.continuing import ThroughputEvaluator

N_ACTIONS = 7
#: greedy evaluation: steps per eval row (every row runs episodes one after the other)
EVAL_HORIZON = 500
EVAL_ROWS = 32
#: MAXQ-Q's step size here (a sweep of 0.01-1.0 on 3 seeds: 0.03 best; ``taxi-fuel-earlier``
#: uses 0.5)
MAXQ_ALPHA = 0.03
#: MAXQ-Q's epsilon, 1 -> 0.01 over the first third of the budget (the sweep: 0.01 beat 0.05)
MAXQ_EXPLORATION = linear_epsilon(1.0, 0.01, Fraction(1, 3))


def text_hierarchy() -> TaskGraph:
    """Dietterich's taxi graph with Refuel; the root over the full 8,750-state index."""
    root = Subtask(
        "Root", ["Get", "Put", "Refuel"], n_states=N_STATES, abstract=lambda o: o["observation"]
    )
    return taxi_fuel_hierarchy(root)


F = FACTORS["fuel_level"]


class FuelNavigate(Navigate):
    """Navigate(t) over (taxi location, fuel): whether the route runs dry depends on the fuel."""

    def __init__(self, target: int) -> None:
        super().__init__(target)
        self.n_states = 25 * F

    def abstract(self, obs):
        return obs["taxi_loc"] * F + obs["fuel_level"]


class FuelNavigateToFuel(NavigateToFuel):
    """Navigate(F) over (taxi location, fuel)."""

    def __init__(self) -> None:
        super().__init__()
        self.n_states = 25 * F

    def abstract(self, obs):
        return obs["taxi_loc"] * F + obs["fuel_level"]


def fuel_aware_hierarchy() -> TaskGraph:
    """``text_hierarchy`` with the fuel added wherever a move can run the tank dry.

    Navigate, Get and Put see the fuel level as well, and so do the four moves (a move's
    reward is -20 at fuel 0): MAXQ's decomposition then keeps the -20 of running dry where the
    root's values can see it (max node irrelevance, Dietterich 2000). Refuel keeps the taxi
    location (it ends with a full tank whatever the fuel was, and starts only below full).
    """
    navs = [FuelNavigate(t) for t in range(4)]
    names = [n.name for n in navs]
    root = Subtask(
        "Root", ["Get", "Put", "Refuel"], n_states=N_STATES, abstract=lambda o: o["observation"]
    )
    get = Subtask(
        "Get", [*names, "Pickup"], n_states=125 * F,
        abstract=lambda o: (o["taxi_loc"] * 5 + o["passenger"]) * F + o["fuel_level"],
        terminated=lambda o: o["passenger"] == IN_TAXI, child_mask=bind_child_mask("passenger"),
    )  # fmt: skip
    put = Subtask(
        "Put", [*names, "Putdown"], n_states=100 * F,
        abstract=lambda o: (o["taxi_loc"] * 4 + o["destination"]) * F + o["fuel_level"],
        terminated=lambda o: o["passenger"] != IN_TAXI, child_mask=bind_child_mask("destination"),
    )  # fmt: skip
    refuel = Subtask(
        "Refuel", ["Navigate_F", "Fillup"], n_states=25, abstract=lambda o: o["taxi_loc"],
        terminated=lambda o: o["fuel"] == CAPACITY,
    )  # fmt: skip
    moves = [Primitive(n, k, F, lambda o: o["fuel_level"]) for k, n in
             enumerate(["South", "North", "East", "West"])]  # fmt: skip
    prims = [*moves, *taxi_primitives()[4:], Primitive("Fillup", 6, 25, lambda o: o["taxi_loc"])]
    nodes = [root, get, put, refuel, *navs, FuelNavigateToFuel(), *prims]
    return TaskGraph("Root", nodes, n_actions=N_ACTIONS)


def make_env(seeds, envs_per_learner: int, backend: str = "torch") -> TaxiFuelTextEnv:
    """The text's taxi-fuel for ``seeds`` (no time limit)."""
    if backend != "torch":
        raise ValueError(f"unknown backend {backend!r}")
    return TaxiFuelTextEnv(seeds, envs_per_learner)


def reward_per_step(config: TrainConfig) -> ThroughputEvaluator:
    """Average reward per step: greedy over ``EVAL_HORIZON`` steps per row, and in training."""
    return ThroughputEvaluator(horizon=EVAL_HORIZON, burn_in=0, unit="reward per step")


def _spec(make_graph, learner, exploration, steps: int, description: str, pg=None) -> AlgoSpec:
    train = TrainConfig(
        steps=steps, eval_every=50_000, eval_episodes=EVAL_ROWS, log_every=20_000,
        success_key="!out_of_fuel",
    )  # fmt: skip
    return AlgoSpec(
        make_graph=make_graph,
        learner=learner,
        exploration=exploration,
        pg=pg,
        train=train,
        envs_per_learner=256,
        description=description,
    )


DOMAIN = DomainSpec(
    name="taxi-fuel",
    description="taxi with fuel as Section 5.2.1 sets it: 8,750 states, average reward per step",
    make_env=make_env,
    make_evaluator=reward_per_step,
    algos={
        "hpgrl": _spec(
            text_hierarchy,
            Make(HPGRLLearner),
            Make(Greedy),  # unused: PG nodes sample
            3_000_000,
            "HPGRL (Algorithm 3), tabular softmax policies, the root over the full state",
            pg=HPGRL_PG,
        ),
        "maxq-q": _spec(
            text_hierarchy,
            Make(MaxQLearner, alpha=MAXQ_ALPHA, gamma=1.0, init=PESSIMISTIC_INIT),
            MAXQ_EXPLORATION,
            1_000_000,
            "MAXQ-Q (Dietterich 2000), the root over the full state",
        ),
        "maxq-q-fuel": _spec(
            fuel_aware_hierarchy,
            Make(MaxQLearner, alpha=0.5, gamma=1.0, init=PESSIMISTIC_INIT),
            epsilon_first_third,
            1_000_000,
            "MAXQ-Q with the fuel in every node where a move can run dry",
        ),
        "q": _spec(
            lambda: flat_graph(N_STATES, N_ACTIONS),
            Make(SMDPQLearner, alpha=0.5, gamma=1.0, init=PESSIMISTIC_INIT),
            epsilon_first_third,
            3_000_000,
            "flat Q-learning over the 8,750 states",
        ),
    },
)
