"""Task graphs of the multi-robot trash collection task (Figures 6.1 and 6.9), for one robot.

Every robot runs its own copy of a graph on its agent row of ``TrashEnv.agent_rows``: its own
fields (``location``, ``carrying``, ``dumped``, ``last_action``) and the shared ones (``cans``,
``t1_full``, ``t2_full``). Task graph of Figure 6.1::

    Root ─┬─ CollectT1 ─┬─ NavT1 ──── North, South, East, West
          │             ├─ NavDump ── North, South, East, West
          │             ├─ Pick
          │             └─ Put
          ├─ CollectT2 ─┬─ NavT2, NavDump, Pick, Put
          └─ Wait

``Wait`` (idle) is a child of ``Root``: the choice of a robot when no can holds trash (both
Collect subtasks are then terminal, so without it ``Root`` would have nothing to choose) and the
action of a robot that waits for its teammates under tau_all. The text's
``U_1 = {collect trash at T1, collect trash at T2}`` thus becomes ``U_1 = {CollectT1,
CollectT2, Wait}`` here. ``NavDump`` is shared by both Collect subtasks (subtask sharing,
Section 3.1).

Communication version (Figure 6.9), one level below the cooperative ``Root``::

    Root ─┬─ Com ────┬─ CollectT1, CollectT2, Wait     (the same subtasks under both)
          └─ NotCom ─┘

Termination: ``CollectTk`` ends where the robot is empty and can ``Tk`` is empty: after its load
is dumped, or when another robot emptied ``Tk`` first. A can refilled while the robot carried
its load keeps the subtask going (it collects at ``Tk`` until ``Tk`` is clear). ``NavX`` ends at
``X``; ``Root`` never ends (the task is continuing). ``Com`` and ``NotCom`` stand for one
decision at ``Root`` (Section 6.5.2) and have no termination of their own: the COM agent
(``hrl_torch.multiagent.cooperative.Communication``) ends them when their ``U_1`` child ends.

State abstractions (the robot's own variables and the cans, Section 3.1: the cans are
irrelevant while navigating):

=============  ===============================================  ======
node           relevant variables                               states
=============  ===============================================  ======
Root           location, carrying, both cans (``own_state``)    96
Com, NotCom    as Root                                          96
CollectTk      location, carrying, can Tk                       48
NavT1/T2/Dump  location                                         12
moves, Pick    none (own reward always -1)                      1
Put            location, carrying                               24
Wait           none (own reward 0)                              1
=============  ===============================================  ======

The primitives' tables hold the team reward, which also carries the other robots' dumps; the
abstraction keeps only what the robot's own action changes.
"""

from __future__ import annotations

from dataclasses import replace
from fractions import Fraction

import torch
from tensordict import TensorDict

from envs.trash import (
    CANS,
    DUMP,
    N_ACTIONS,
    N_CELLS,
    N_OWN_STATES,
    N_ROBOT_CODES,
    PICK,
    PUT,
    REFILL_PROB,
    WAIT,
    TrashEnv,
)
from hrl_torch.common.config import Make
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner
from hrl_torch.learners.neural_maxq import NeuralMaxQLearner
from hrl_torch.modules.exploration import linear_epsilon
from hrl_torch.modules.schedules import VisitCount
from hrl_torch.multiagent.cooperative import Cooperation, MultiAgentConfig, cooperative_graph
from hrl_torch.runs.domain import AlgoSpec, DomainSpec, algo_family
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.continuing import ThroughputEvaluator

MOVE_NAMES = ["North", "South", "East", "West"]
#: the children of the cooperative Root (Figure 6.1) or of Com / NotCom (Figure 6.9)
U1 = ("CollectT1", "CollectT2", "Wait")
ROOT_STATES = N_OWN_STATES  # 96
COLLECT_STATES = N_ROBOT_CODES * 2  # 48


def _robot(obs: TensorDict) -> torch.Tensor:
    """``location * 2 + carrying`` of the agent row."""
    return obs["location"] * 2 + obs["carrying"]


def _navigate(name: str, cell: int) -> Subtask:
    """Navigate to ``cell``; abstraction: location."""
    return Subtask(
        name,
        MOVE_NAMES,
        n_states=N_CELLS,
        abstract=lambda o: o["location"],
        terminated=lambda o: o["location"] == cell,
    )


def _collect(k: int) -> Subtask:
    """Collect trash at ``T(k+1)``: navigate there, pick, navigate to the Dump, put."""
    full = f"t{k + 1}_full"
    return Subtask(
        f"CollectT{k + 1}",
        [f"NavT{k + 1}", "NavDump", "Pick", "Put"],
        n_states=COLLECT_STATES,
        abstract=lambda o: _robot(o) * 2 + o[full],
        terminated=lambda o: (o["carrying"] == 0) & (o[full] == 0),
    )


def _root_state(obs: TensorDict) -> torch.Tensor:
    return obs["own_state"]


def _collection_nodes() -> list[Subtask | Primitive]:
    """Everything below the U_1 level: the Collect and Nav subtasks and the primitives."""
    return [
        _collect(0),
        _collect(1),
        _navigate("NavT1", CANS[0]),
        _navigate("NavT2", CANS[1]),
        _navigate("NavDump", DUMP),
        Primitive("South", 0),
        Primitive("North", 1),
        Primitive("East", 2),
        Primitive("West", 3),
        Primitive("Pick", PICK),
        Primitive("Put", PUT, N_ROBOT_CODES, _robot),
        Primitive("Wait", WAIT),
    ]


def trash_hierarchy() -> TaskGraph:
    """The task graph of Figure 6.1 for one robot (``Root`` is the cooperative subtask)."""
    root = Subtask("Root", U1, n_states=ROOT_STATES, abstract=_root_state)
    return TaskGraph("Root", [root, *_collection_nodes()], n_actions=N_ACTIONS)


def trash_com_hierarchy() -> TaskGraph:
    """The task graph of Figure 6.9: Root -> Com, NotCom -> U_1 (shared subtasks)."""
    root = Subtask("Root", ["Com", "NotCom"], n_states=ROOT_STATES, abstract=_root_state)
    levels = [
        Subtask(name, U1, n_states=ROOT_STATES, abstract=_root_state) for name in ("Com", "NotCom")
    ]
    return TaskGraph("Root", [root, *levels, *_collection_nodes()], n_actions=N_ACTIONS)


# ---------------------------------------------------------------------- experiments (Ch. 6)
GAMMA = 0.95  # per step
INIT = -10.0  # pessimistic initial completions (zero ones are optimistic here: greedy loops)
COOPERATION = Cooperation((("Root",),), wait="Wait")


#: training restarts every robot at a random cell after this many steps (see ``make_env``)
RESTART_EVERY = 100


def make_env(
    seeds,
    envs_per_learner: int,
    backend: str = "torch",
    n_agents: int = 2,
    restart_every: int | None = RESTART_EVERY,
    refill_prob: float = REFILL_PROB,
):
    """The trash collection task with ``n_agents`` robots for ``seeds`` (training).

    Each robot learns from its own share of the team reward (``own_rewards``): with the
    team's reward, two learning robots stayed near a gain of 0.05 where one robot alone
    learns 1.0 (each saw the other's +20s as noise in its primitive values).

    The task is continuing, and ``Root`` chooses almost only at the Dump, so the start cells
    are seen once per env row. Untrained there, a greedy robot may choose ``Wait`` (own reward
    0) and wait forever: one robot's exact gain was 0.22 (optimum 1.17) without restarts and
    1.10 with a restart every 100 steps (5 seeds, 150k steps).
    """
    return TrashEnv(
        seeds,
        envs_per_learner,
        n_agents,
        refill_prob,
        max_episode_steps=restart_every,
        own_rewards=True,
    )


def make_eval_env(
    seeds, envs_per_learner: int, backend: str = "torch", n_agents: int = 2, **options
):
    """The evaluation env: the long run, no restarts."""
    options["restart_every"] = None
    return make_env(seeds, envs_per_learner, backend, n_agents, **options)


_MAXQ = Make(MaxQLearner, alpha=0.2, gamma=GAMMA, init=INIT)


#: initial joint completions of the cooperative root: optimistic (0, not ``INIT``), so that a
#: robot tries each choice with each task of the other robot (4 x as many root entries as a
#: selfish root; with -10 most stayed untried: exact gain 1.367 -> 1.416, 5 seeds)
COOPERATIVE_ROOT_INIT = 0.0


_MAXQ_COOPERATIVE = _MAXQ.with_argument("init_nodes", {"Root": COOPERATIVE_ROOT_INIT})


#: Cooperative HRL with MLP completions (issue 36; hrl_torch.learners.neural_maxq): taxi's
#: network settings, the tables' targets, discount and initial values
_MAXQ_COOPERATIVE_MLP = Make(
    NeuralMaxQLearner,
    alpha=0.2,
    gamma=GAMMA,
    lr=0.002,
    init=INIT,
    updates=8,
    init_nodes={"Root": COOPERATIVE_ROOT_INIT},
)


#: the per-entry step size of the ``-visits`` algorithms: ``clip(1 / n, LOW, HIGH)``
VISIT_STEP = (0.2, 0.01)
#: their budget: the 1/n step size pays off with a longer run (issue 22: Cooperative 1.437 at
#: 150,000 steps, 1.467 at 600,000; docs/reproduction.md, trash)
VISIT_STEPS = 600_000


def visit_step_size(learner: MaxQLearner, high: float, low: float) -> MaxQLearner:
    """Give every table entry of a built ``learner`` its own step size ``clip(1 / n, low, high)``.

    ``n`` counts the entry's updates so far, this one included (Section 6.3: ``alpha_t(i)``
    "should be gradually decreased to zero"; the floor ``low`` keeps tracking the other
    robot's changing policy): ``hrl_torch.modules.schedules.VisitCount``, which a tabular
    learner also takes as its ``alpha``. The counts are its tables' buffer ``visits``.
    """
    steps = VisitCount(low, high)  # (checks 0 <= low <= high <= 1)
    learner.tables.count_visits()
    learner.alpha = steps
    return learner


#: the ``-visits`` algorithms' step size
_VISITS = VisitCount(VISIT_STEP[1], VISIT_STEP[0])


def maxq_visits(graph: TaskGraph, sets: int) -> MaxQLearner:
    """The selfish robots' MAXQ-Q with the per-entry step size ``clip(1 / n, 0.01, 0.2)``."""
    return _MAXQ.with_argument("alpha", _VISITS).build(graph, sets)


def maxq_cooperative_visits(graph: TaskGraph, sets: int) -> MaxQLearner:
    """The cooperative root's MAXQ-Q with the per-entry step size ``clip(1 / n, 0.01, 0.2)``."""
    return _MAXQ_COOPERATIVE.with_argument("alpha", _VISITS).build(graph, sets)


def _evaluator(config: TrainConfig) -> ThroughputEvaluator:
    """The team's reward per step (the gain), greedy and in training."""
    return ThroughputEvaluator(horizon=500, burn_in=100, unit="team reward per step")


def _algos() -> dict[str, AlgoSpec]:
    spec = algo_family(
        learner=_MAXQ,
        exploration=linear_epsilon(0.5, 0.02, Fraction(1, 2)),
        train=TrainConfig(steps=60_000, eval_every=10_000, eval_episodes=16),
        envs_per_learner=16,
    )

    cooperative = replace(
        spec(
            lambda: cooperative_graph(trash_hierarchy(), COOPERATION, 2),
            "Cooperative HRL: the root's completions know the other robot's U_1 task",
            MultiAgentConfig(COOPERATION),
        ),
        learner=_MAXQ_COOPERATIVE,
    )
    selfish = spec(trash_hierarchy, "selfish multi-agent HRL: each robot learns alone")
    longer = replace(spec(trash_hierarchy, "").train, steps=VISIT_STEPS)
    visits = " with a per-entry 1/n step size in [0.01, 0.2], 600,000 steps"
    return {
        "cooperative": cooperative,
        "cooperative-mlp": replace(
            cooperative,
            learner=_MAXQ_COOPERATIVE_MLP,
            description="Cooperative HRL with MLP completions (one-hot states, Adam)",
        ),
        "selfish": selfish,
        "single": spec(trash_hierarchy, "single-agent HRL: one robot", n_agents=1),
        "cooperative-visits": replace(
            cooperative,
            learner=Make(maxq_cooperative_visits),
            train=longer,
            description="Cooperative HRL" + visits,
        ),
        "selfish-visits": replace(
            selfish, learner=Make(maxq_visits), train=longer, description="selfish HRL" + visits
        ),
    }


DOMAIN = DomainSpec(
    name="trash",
    description="two robots collecting trash (Figures 3.1, 6.1), discrete time, continuing",
    make_env=make_env,
    algos=_algos(),
    make_evaluator=_evaluator,
    make_eval_env=make_eval_env,
)
