"""Task graphs of the multi-taxi domain (Section 6.6, Figure 6.10) for one taxi, and their sizes.

Every taxi runs its own copy of a graph on its agent row of ``TwoTaxiEnv.agent_rows``: its own
fields (``taxi_loc``, ``status``, ``picked_up``, ``delivered``, ``last_action``) and the shared
station statuses (``stations``, ``waiting_R`` ... ``waiting_B``). Task graph of Figure 6.10::

    Root ─┬─ GetB, GetG, GetR, GetY ─┬─ Navigate(s) ── North, South, East, West
          │                          └─ Pickup
          ├─ Wait
          └─ Put ─┬─ Navigate(R), Navigate(G), Navigate(Y), Navigate(B)
                  └─ Putdown

``Get_s`` calls ``Navigate(s)`` for its own station and offers ``Pickup`` only there; ``Put``'s
mask allows only the ``Navigate(t)`` of the carried passenger's destination and ``Putdown``
only there. (Without these masks a greedy taxi met illegal pickups at unseen states and
repeated them: the tables are frozen during evaluation.) ``Navigate(t)`` is Dietterich's,
shared by Get and Put, with an internal cost per move (``StepCostNavigate``). ``Root`` is the
cooperative subtask and ``U_1 = {GetB, GetG, GetR, GetY, Wait, Put}``. COM version (the
communication level)::

    Root ─┬─ Com ────┬─ GetB, GetG, GetR, GetY, Wait, Put   (the same subtasks under both)
          └─ NotCom ─┘

Two tasks are registered, with the same learners (``hrl-torch list``):

- ``two-taxi`` and ``two-taxi-station``, the task as Section 6.6 describes it:
  ``Get_s`` starts only where ``s`` has a passenger and ends with a pickup or *at* ``s`` with
  nobody there: "the first taxi picks up the passenger and the other one returns empty" (the
  loser of a race drives on to the station; a passenger who arrived meanwhile is its own).
  Every taxi learns from the one team reward (+20 per delivery, -1 per waiting passenger and
  step, -10 per illegal action: ``make_text_env``). Footnote 4's arrival rate is read over the
  grid (``two-taxi``: one arrival every ``rate`` steps on average) or per station
  (``two-taxi-station``: every station its own). ``Navigate(t)`` is ``TeamNavigate``:
  -5 per move inside it and no moves into walls, because the team reward's noise (the other
  taxi's deliveries) in the moves' values made greedy taxis bump into walls forever;
- ``two-taxi-earlier``, the first build: ``Get_s`` ends as soon as station ``s`` has no passenger
  (another taxi took it), so a lost race costs nothing after the pickup; each taxi learns from
  its own share of the reward (its deliveries and illegal actions, half the waiting cost).

``agents.two_taxi_rules`` holds hand-written dispatching rules on the same tasks (racing for the
nearest passenger, or coordinated choices): they measure how much room the task leaves for
coordination.

Termination: ``Get_s`` as above; ``Put`` when the taxi is empty; ``Navigate(t)`` at ``t``;
``Root`` never (the task is continuing). ``Com`` / ``NotCom`` stand for one decision and have
no termination of their own: the COM agent (``hrl_torch.multiagent.cooperative.Communication``)
ends them when their ``U_1`` child ends, so every ``U_1`` decision is preceded by a communication
decision.

State abstractions: each taxi stores only its own variables and the stations' statuses
(``4**4 = 256``):

=============  ===============================================  ======
node           relevant variables                               states
=============  ===============================================  ======
Root           location, loaded (status != empty), stations     12,800
Com, NotCom    as Root                                          12,800
Get_s          location, stations                               6,400
Put            location, status                                 125
Navigate(t)    location                                         25
N/S/E/W        none (leaf irrelevance)                          1
Pickup         location, stations                               6,400
Putdown        location, status                                 125
Wait           stations (its reward: the waiting passengers)    256
=============  ===============================================  ======

``Root`` keeps "loaded" rather than the destination: a loaded taxi's only useful choice is
``Put``; ``Get_s`` keeps all stations because the reward inside it (-1 per waiting passenger
and step) depends on all of them.

Table sizes (``count_values``: a subtask stores ``n_states x n_children`` completion values,
times ``|U_1|**(n-1)`` columns for a cooperative subtask indexed by the other taxis' actions in
``U_1``; a primitive ``n_states`` values), per taxi:

======================  ===========  ===========  ==================
algorithm               ours         text         difference
======================  ===========  ===========  ==================
selfish multi-agent     135,810      135,895      -85 (-0.06%)
Cooperative HRL         519,810      729,815      -210,005 (-28.8%)
COM-Cooperative HRL     622,210      934,615      -312,405 (-33.4%)
======================  ===========  ===========  ==================

Ours: Root 76,800 + Get 4 x 12,800 + Put 625 + Navigate 4 x 100 + primitives 6,785 = 135,810;
the Cooperative root has 12,800 x 6 x 6 = 460,800 values; the COM graph has Root 25,600, Com
460,800 and NotCom 76,800. The text gives no abstraction, and its three numbers do not follow
from one rule applied to a full table: indexing ``Root``'s table (``n`` states x 6 children)
by the other taxi's action in ``U_1`` adds ``30 n`` values, a multiple of 3, but the text's
increase 729,815 - 135,895 = 593,920 is not divisible by 3. Both of its increases are
multiples of 20,480 (593,920 = 29 x 20,480; 204,800 = 10 x 20,480), as if ``Root`` had 20,480
states and the cooperative version replaced 7 values per state (6 completions and a value) by
36 joint completions while the COM version added 10 (2 at Root, 6 at NotCom, a value each for
Com and NotCom); but 20,480 x 7 already exceeds the selfish total, and 20,480 = 5 x 16 x 256
has no factor 25 for the location. The text's counts probably skip unavailable (state, child)
pairs or store values we cannot infer, so only the selfish count is reproduced closely.
"""

from __future__ import annotations

from collections.abc import Mapping
from fractions import Fraction
from functools import partial

import torch
from tensordict import TensorDict

from agents.taxi import Navigate
from envs.two_taxi import (
    EAST,
    EMPTY,
    MEAN_INTERARRIVAL,
    MOVES,
    N_ACTIONS,
    N_LOCATIONS,
    N_STATIONS,
    N_STATIONS_STATES,
    N_STATUS,
    NORTH,
    PICKUP,
    PUTDOWN,
    SOUTH,
    STATION_LOC,
    STATION_NAMES,
    THROUGHPUT_WINDOW,
    WAIT,
    WEST,
    TwoTaxiEnv,
)
from hrl_torch.common.config import Make
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import linear_epsilon
from hrl_torch.multiagent.cooperative import (
    Communication,
    Cooperation,
    MultiAgentConfig,
    cooperative_graph,
)
from hrl_torch.runs.domain import AlgoSpec, DomainSpec, algo_family
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.continuing import ThroughputEvaluator

#: the text's order of the Root's children: U_1
U1 = ("GetB", "GetG", "GetR", "GetY", "Wait", "Put")
NAVIGATE = [f"Navigate_{name}" for name in STATION_NAMES]
ROOT_STATES = N_LOCATIONS * 2 * N_STATIONS_STATES  # 12,800
GET_STATES = N_LOCATIONS * N_STATIONS_STATES  # 6,400
PUT_STATES = N_LOCATIONS * N_STATUS  # 125
#: the dissertation's counts of C and V values per taxi (Section 6.6)
TEXT_TABLE_SIZES = {"selfish": 135_895, "cooperative": 729_815, "com_cooperative": 934_615}


class StepCostNavigate(Navigate):
    """Navigate(t) with an internal reward of -1 per move (Section 3.1's internal rewards).

    Moves cost nothing outside (only waiting passengers do), and where nobody waits nothing
    teaches the shortest path; the internal cost does, inside Navigate only (MAXQ-Q's
    internal completions choose with it, the values Get and Put read do not see it).
    """

    def shaping_reward(self, obs: TensorDict, action, next_obs: TensorDict) -> torch.Tensor:
        """-1 per move."""
        return -torch.ones(action.shape[0], device=action.device)


class TeamNavigate(StepCostNavigate):
    """Navigate(t) of the text's task (team reward): -``cost`` per move, no moves into walls.

    With one team reward a move's reward holds the other taxi's deliveries (+20 now and
    then), so the moves' values ``V(North)`` ... (one state each, leaf irrelevance) jump by
    ``alpha * 20 = 4`` whenever the other taxi delivers during one of them. With -1 per move a
    greedy taxi with frozen tables then bumped into a wall forever when that move's value was
    above 1 (seen: ``V(West) = 3.8``, the taxi stuck at (1, 2); greedy throughput 0 in 3 of 5
    selfish seeds at 20,000-80,000 steps). Moves that stay put are masked (no self-loop) and
    each move costs ``cost`` inside Navigate (a two-move cycle needs both values above it).
    """

    def __init__(self, target: int, cost: float) -> None:
        super().__init__(target)
        self.cost = float(cost)
        # where each location's North, South, East, West lead: a constant moved with the graph
        moves = MOVES[:, [NORTH, SOUTH, EAST, WEST]].clone()
        self.register_buffer("moves", moves, persistent=False)

    def shaping_reward(self, obs: TensorDict, action, next_obs: TensorDict) -> torch.Tensor:
        """-``cost`` per move."""
        return torch.full((action.shape[0],), -self.cost, device=action.device)

    def child_mask(self, obs: TensorDict) -> torch.Tensor:
        """``[B, 4]``: North, South, East, West where they leave the square."""
        loc = obs["taxi_loc"]
        return self.moves[loc] != loc[:, None]


def _root_state(obs: TensorDict) -> torch.Tensor:
    loaded = (obs["status"] != EMPTY).long()
    return (obs["taxi_loc"] * 2 + loaded) * N_STATIONS_STATES + obs["stations"]


def _loc_stations(obs: TensorDict) -> torch.Tensor:
    return obs["taxi_loc"] * N_STATIONS_STATES + obs["stations"]


def _loc_status(obs: TensorDict) -> torch.Tensor:
    return obs["taxi_loc"] * N_STATUS + obs["status"]


def _get(station: int, text: bool = False) -> Subtask:
    """Get_s: drive to station ``s`` and pick its passenger up (Pickup only at ``s``).

    ``text``: the text's rule ("the first taxi picks up the passenger and the other one returns
    empty", Section 6.6): Get_s starts only where ``s`` has a passenger and ends with a pickup
    or at ``s`` with nobody there; a taxi whose passenger another took drives on to ``s``.
    Otherwise (the race variant) it ends as soon as ``s`` has no passenger.
    """
    name = STATION_NAMES[station]
    waiting = f"waiting_{name}"
    at = int(STATION_LOC[station])

    def mask(obs: TensorDict) -> torch.Tensor:
        there = obs["taxi_loc"] == at
        return torch.stack([~there, there], dim=1)

    def ended(obs: TensorDict) -> torch.Tensor:
        nobody = obs[waiting] == 0
        if text:  # only at the station
            nobody = nobody & (obs["taxi_loc"] == at)
        return (obs["status"] != EMPTY) | nobody

    return Subtask(
        f"Get{name}",
        [NAVIGATE[station], "Pickup"],
        n_states=GET_STATES,
        abstract=_loc_stations,
        terminated=ended,
        initiable=(lambda o: o[waiting] != 0) if text else None,
        child_mask=mask,
    )


class _Put(Subtask):
    """Put: deliver the carried passenger (``Navigate(t)`` to its destination, ``Putdown``)."""

    def __init__(self) -> None:
        super().__init__(
            "Put",
            [*NAVIGATE, "Putdown"],
            n_states=PUT_STATES,
            abstract=_loc_status,
            terminated=lambda o: o["status"] == EMPTY,
        )
        # the stations' locations: a constant moved with the graph
        self.register_buffer("station_loc", STATION_LOC.clone(), persistent=False)

    def child_mask(self, obs: TensorDict) -> torch.Tensor:
        """``[B, 5]``: Navigate(t) for the destination ``t`` away from it; Putdown at it."""
        status = obs["status"]
        nav = status[:, None] == torch.arange(N_STATIONS, device=obs.device)[None, :]
        there = obs["taxi_loc"] == self.station_loc[status.clamp_max(N_STATIONS - 1)]
        return torch.cat([nav & ~there[:, None], there[:, None]], dim=1)


def _below_u1(text: bool = False) -> list[Subtask | Primitive]:
    """The U_1 subtasks (but Wait, a primitive) and everything below them (``_get``'s text)."""
    put = _Put()
    return [
        *(_get(s, text) for s in range(N_STATIONS)),
        put,
        *(
            TeamNavigate(t, TEAM_NAV_COST) if text else StepCostNavigate(t)
            for t in range(N_STATIONS)
        ),
        Primitive("South", 0),
        Primitive("North", 1),
        Primitive("East", 2),
        Primitive("West", 3),
        Primitive("Pickup", PICKUP, GET_STATES, _loc_stations),
        Primitive("Putdown", PUTDOWN, PUT_STATES, _loc_status),
        Primitive("Wait", WAIT, N_STATIONS_STATES, lambda o: o["stations"]),
    ]


def two_taxi_hierarchy(text: bool = False) -> TaskGraph:
    """The task graph of Figure 6.10 for one taxi, without the communication level.

    ``text``: Get_s ends only at its station (``_get``).
    """
    root = Subtask("Root", U1, n_states=ROOT_STATES, abstract=_root_state)
    return TaskGraph("Root", [root, *_below_u1(text)], n_actions=N_ACTIONS)


def two_taxi_com_hierarchy(text: bool = False) -> TaskGraph:
    """Figure 6.10 with the communication level: Root -> Com, NotCom -> U_1 (shared)."""
    root = Subtask("Root", ["Com", "NotCom"], n_states=ROOT_STATES, abstract=_root_state)
    levels = [
        Subtask(name, U1, n_states=ROOT_STATES, abstract=_root_state) for name in ("Com", "NotCom")
    ]
    return TaskGraph("Root", [root, *levels, *_below_u1(text)], n_actions=N_ACTIONS)


def value_counts(graph: TaskGraph, joint: Mapping[str, int] | None = None) -> dict[str, int]:
    """Values each node of ``graph`` stores, by name.

    A subtask stores ``n_states x n_children`` completion values (times ``joint[name]`` for a
    cooperative subtask whose table is also indexed by the other agents' actions), a primitive
    ``n_states`` values.

    Args:
        graph: the task graph of one agent.
        joint: columns per cooperative subtask, ``|U_l| ** (n_agents - 1)``.
    """
    joint = dict(joint or {})
    unknown = sorted(set(joint) - set(graph.names))
    if unknown:
        raise ValueError(f"joint names subtasks not in the graph: {unknown}")
    counts = {}
    for node in graph.nodes:
        if node.is_primitive:
            counts[node.name] = node.n_states
        else:
            counts[node.name] = node.n_states * len(node.children_names) * joint.get(node.name, 1)
    return counts


def count_values(graph: TaskGraph, joint: Mapping[str, int] | None = None) -> int:
    """Total C and V values of one agent's ``graph`` (see ``value_counts``)."""
    return sum(value_counts(graph, joint).values())


def table_sizes(n_agents: int = 2) -> dict[str, int]:
    """Values per taxi for the selfish, Cooperative and COM-Cooperative learners."""
    others = len(U1) ** (n_agents - 1)
    return {
        "selfish": count_values(two_taxi_hierarchy()),
        "cooperative": count_values(two_taxi_hierarchy(), {"Root": others}),
        "com_cooperative": count_values(two_taxi_com_hierarchy(), {"Com": others}),
    }


# ---------------------------------------------------------------------- experiments (Ch. 6)
GAMMA = 0.95  # per step
INIT = 0.0  # external completions below the U_1 parents
#: pessimistic internal completions inside Navigate (the longest route's discounted cost)
INIT_INTERNAL = -10.0
#: the text's task: Navigate's internal cost per move (``TeamNavigate``); its internal
#: completions start at ``INIT_INTERNAL * TEAM_NAV_COST``
TEAM_NAV_COST = 5.0
#: Initial completions at the U_1 parents (Root, Com, NotCom): optimistic for the tasks that
#: serve passengers, pessimistic for Wait. With 0 for all, a greedy taxi waited forever at root
#: states it had not met in training (frozen tables; the root's state holds every station and,
#: for Cooperative HRL, the other taxi's task): Wait costs one step of waiting passengers, a Get
#: or Put many, and the deliveries they lead to live in the completions still at 0. Greedy
#: throughput was 368 and 407 (selfish) and 276 and 303 (cooperative) against 440-445 in
#: training (2 seeds, 200k steps).
SERVE_INIT = 10.0
WAIT_INIT = -10.0
#: Cooperative HRL: Root is the cooperative subtask; a taxi without a U_1 task counts as waiting
COOPERATION = Cooperation((("Root",),), idle="Wait")
#: COM-Cooperative HRL: Com is the cooperative subtask (Figure 6.10)
COM_COOPERATION = Cooperation((("Com",),), idle="Wait")
#: the text's communication costs (Figure 6.14)
COM_COSTS = (0, 1, 5, 10)


def make_env(
    seeds,
    envs_per_learner: int,
    backend: str = "torch",
    n_agents: int = 2,
    mean_interarrival: float = MEAN_INTERARRIVAL,
):
    """The two-taxi-earlier task for ``seeds``; each taxi learns from its own share of reward."""
    return TwoTaxiEnv(
        seeds,
        envs_per_learner,
        n_agents,
        mean_interarrival,
        max_episode_steps=None,
        own_rewards=True,
    )


def make_text_env(
    seeds,
    envs_per_learner: int,
    backend: str = "torch",
    n_agents: int = 2,
    mean_interarrival: float = MEAN_INTERARRIVAL,
    arrivals: str = "grid",
):
    """The text's task: every taxi learns from the one team reward (deliveries, waiting)."""
    return TwoTaxiEnv(
        seeds,
        envs_per_learner,
        n_agents,
        mean_interarrival,
        max_episode_steps=None,
        own_rewards=False,
        arrivals=arrivals,
    )


def maxq_learner(
    graph: TaskGraph, sets: int, alpha: float = 0.2, nav_cost: float = 1.0
) -> MaxQLearner:
    """MAXQ-Q; the U_1 parents' completions start at ``SERVE_INIT`` / ``WAIT_INIT``."""
    learner = MaxQLearner(
        graph, sets, alpha=alpha, gamma=GAMMA, init=INIT, init_internal=INIT_INTERNAL * nav_cost
    )
    with torch.no_grad():
        for parent in ("Root", "Com", "NotCom"):
            if parent not in graph.index or "Wait" not in graph.node(parent).children_names:
                continue
            wait = graph.node(parent).children_names.index("Wait")
            for table in learner.heads[parent].views().values():
                table.fill_(SERVE_INIT)
                table[..., wait] = WAIT_INIT
    return learner


def _delivered(td: TensorDict) -> torch.Tensor:
    return td["n_delivered"]


def _wait_delivered(td: TensorDict) -> torch.Tensor:
    return td["wait_delivered"]


def _evaluator(config: TrainConfig) -> ThroughputEvaluator:
    """Deliveries per 5,000 steps and the waiting time per delivered passenger."""
    return ThroughputEvaluator(
        horizon=2_000,
        burn_in=200,
        metric=_delivered,
        scale=THROUGHPUT_WINDOW,
        unit="passengers per 5,000 steps",
        ratio=(_wait_delivered, _delivered),
        ratio_tags=("charts/eval_wait", "charts/wait"),
    )


def com_graph(text: bool = False) -> TaskGraph:
    """The COM graph with ``Com``'s completions joint over the other taxi's U_1 task."""
    return cooperative_graph(two_taxi_com_hierarchy(text), COM_COOPERATION, 2)


def cooperative_two_taxi_graph(text: bool = False) -> TaskGraph:
    """Cooperative HRL's graph: Root's completions joint over the other taxi's U_1 task."""
    return cooperative_graph(two_taxi_hierarchy(text), COOPERATION, 2)


def _algos(text: bool = False, **env_options) -> dict[str, AlgoSpec]:
    """The learners of Section 6.6 (``text``: on the graphs whose Get ends at its station)."""
    spec = algo_family(
        learner=Make(maxq_learner, nav_cost=TEAM_NAV_COST if text else 1.0),
        exploration=linear_epsilon(0.5, 0.02, Fraction(1, 2)),
        train=TrainConfig(steps=200_000, eval_every=20_000, eval_episodes=4),
        envs_per_learner=16,
    )
    flat = partial(two_taxi_hierarchy, text)
    com = partial(com_graph, text)
    algos = {
        "selfish": spec(flat, "selfish multi-agent HRL: each taxi learns alone", **env_options),
        "cooperative": spec(
            partial(cooperative_two_taxi_graph, text),
            "Cooperative HRL: Root's completions know the other taxi's U_1 task",
            MultiAgentConfig(COOPERATION),
            **env_options,
        ),
        "single": spec(flat, "single-agent HRL: one taxi", n_agents=1, **env_options),
    }
    for cost in COM_COSTS:
        algos[f"com-{cost}"] = spec(
            com,
            f"COM-Cooperative HRL, ComCost {cost}: Root chooses Com (asks) or NotCom",
            MultiAgentConfig(COM_COOPERATION, communication=Communication(cost=float(cost))),
            **env_options,
        )
    for loss in (50, 100):  # beyond the text: replies lost with probability loss %
        algos[f"com-0-loss{loss}"] = spec(
            com,
            f"COM-Cooperative HRL, ComCost 0, {loss}% of the replies lost",
            MultiAgentConfig(COM_COOPERATION, communication=Communication(loss=loss / 100)),
            **env_options,
        )
    return algos


#: the first build: a Get ends when its passenger is gone, arrivals over the grid, own rewards
DOMAIN = DomainSpec(
    name="two-taxi-earlier",
    description="two taxis, the reading before Section 6.6's (kept for comparison)",
    make_env=make_env,
    algos=_algos(),
    make_evaluator=_evaluator,
)
#: the text's task: Get ends at its station (the loser returns empty), one team reward
DOMAIN_TEXT = DomainSpec(
    name="two-taxi",
    description="two taxis as Section 6.6 builds them: a race's loser returns empty, team "
    "reward, one arrival process over the grid",
    make_env=make_text_env,
    algos=_algos(text=True),
    make_evaluator=_evaluator,
)
#: the text's task, footnote 4 read per station: each station its own arrival process
DOMAIN_TEXT_STATION = DomainSpec(
    name="two-taxi-station",
    description="two-taxi with an arrival process per station (footnote 4 per station)",
    make_env=make_text_env,
    algos=_algos(text=True, arrivals="station"),
    make_evaluator=_evaluator,
)


if __name__ == "__main__":
    for key, ours in table_sizes().items():
        text = TEXT_TABLE_SIZES[key]
        print(f"{key:16s} ours {ours:>9,}  text {text:>9,}  difference {ours - text:>+9,}")
