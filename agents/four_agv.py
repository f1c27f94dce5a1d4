"""The four-AGV task graph of Figure 6.3 and the AGV dispatching rules of Figure 6.7.

This is the ``four-agv-earlier`` domain, the first reading of Section 6.4: jobs end when their item
is gone, the root sees which jobs can start, each AGV learns from its own deliveries and the rules
are centralised with reservations. ``agents/four_agv_text.py`` (``four-agv``) is the
reading closer to the text (committed jobs that wait, a buffer-level root, one team reward,
per-AGV rules); both are kept and measured (``docs/reproduction.md``).

Task graph (one copy per agent; each agent row of ``FourAGVEnv.agent_rows`` is its
observation)::

    Root ─┬─ DM_i ─┬─ Nav_W_i ─┐                     i = 1..4: deliver material to Mi
          │        ├─ Nav_D_i ─┤
          │        └─ Load, Unload, Idle
          ├─ DA_i ─┬─ Nav_P_i ─┼─ Forward, Left, Right
          │        ├─ Nav_WA ──┘                     (Nav_WA shared by DA_1..4)
          │        └─ Load, Unload                   i = 1..4: deliver assembly from Mi
          └─ Idle

``Nav_t`` is one subtask per target location ``t`` (13 of them). The status binds the
children: an empty AGV may only call ``Nav_W_i``/``Nav_P_i`` and ``Load``, a loaded one only
``Nav_D_i``/``Nav_WA`` and ``Unload`` (``child_mask``). ``DM_i`` also has ``Idle``, available
only while the AGV carries part ``i`` and ``Di`` is full: with several AGVs a buffer can fill
while an AGV is on its way (the "wait for a long time" of Section 6.4), and without a way to
wait the AGV could only repeat failing 1 ms unloads. The root is the cooperative subtask of
Cooperative HRL (Section 6.4): its children ``DM_1..4, DA_1..4`` (and ``Idle``) form ``U_1``;
the learner, not the graph, adds the other agents' current ``U_1`` actions to its tables.

State abstractions (buffer capacity ``c``; the text's counts are for ``c = 3``):

=========  ===========================================================  ===================
node       relevant variables                                           states (c = 3)
=========  ===========================================================  ===================
Root       one bit per ``DM_i`` / ``DA_i``: can it start now             2**8 = 256
DM_i       location, status, drop_off_i, warehouse_i                    100 x 9 x 4 x 2 = 7,200
DA_i       location, status, pick_up_i                                  100 x 9 x 4 = 3,600
Nav_t      location                                                     100
Unload     location, status (its reward depends on them)                900
others     none                                                         1
=========  ===========================================================  ===================

The text does not give the root's abstraction. Its decisions are made with an empty AGV (DM/DA
end on a delivery, or when the job is gone, with the AGV empty), so the status is constant
there; and with 1 ms moves the AGV's location hardly matters for which job to take next (with
the 2 s moves of Figure 6.5 it does: adding it multiplies the root's states by 100). What
matters is which jobs can start: ``DM_i`` when part ``i`` waits and ``Di`` has room, ``DA_i``
when ``Pi`` holds an assembly, i.e. the initiation sets of the eight children. The root's
table is then 256 states x 9 children per agent, and Cooperative HRL's joint table with the
other three agents' ``U_1`` actions (9 values each, ``Idle`` included) 256 x 9**3 x 9 =
1,679,616 entries: small enough for a population of learners. (The full buffer state, as the
root of ``agents/agv.py`` uses, would be ``100 x 4**8 x 2**4``, about 10**8 states.)

Initiation and termination (``delivery`` is what the agent's last action delivered):

* ``DM_i``: initiable when the AGV is empty, part ``i`` waits in the warehouse and ``Di`` has
  room, or when it carries part ``i``; terminates when part ``i`` is delivered into ``Di``
  (``delivery == i``), when the AGV carries anything else, or when it is empty and part ``i`` is
  gone or ``Di`` is full (another AGV got there first).
* ``DA_i``: initiable when the AGV is empty and ``Pi`` holds an assembly, or when it carries
  assembly ``i``; terminates when assembly ``i`` is delivered (``delivery == 4 + i``), when the
  AGV carries anything else, or when it is empty and ``Pi`` is empty.
* ``Nav_t``: terminates at ``t``.

``DM_i`` and ``DA_i`` are *event-terminated* (``event_termination``): a delivery ends the
running invocation but does not make the subtask unavailable where ``delivery`` still shows it,
so the root may start the same job again at once (unlike ``agents/agv.py``, whose root must
pick another child first). Their other terminal states are outside their initiation sets, so
they stay unavailable there.

``flat_graph`` is the flat alternative (one root over the primitives on the agent's flat
state) for the flat Q-learner of Figure 6.6. The dispatching rules of Figure 6.7 are batched
rule policies over the agent rows: ``FirstComeFirstServe``, ``HighestQueueFirst`` and
``NearestStationFirst`` (see ``DispatchRule``).
"""

from __future__ import annotations

from fractions import Fraction

import torch
from tensordict import TensorDict

from agents.four_agv_rules import DISPATCH_RULES, N_JOBS
from envs.four_agv import (
    BAYS,
    CAPACITY,
    DROP_OFF,
    EMPTY,
    FIGURE_6_5,
    FORWARD,
    IDLE,
    LEFT,
    LOAD,
    N_ACTIONS,
    N_LOCATIONS,
    N_STATIONS,
    N_STATUS,
    PICK_UP,
    RIGHT,
    TABLE_6_1,
    UNLOAD,
    WAREHOUSE_DROP,
    FourAGVEnv,
    FourAGVTiming,
    n_flat_states,
    successors,
)
from hrl_torch.common.config import Make
from hrl_torch.common.devices import constant_on
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner, RuleLearner, SMDPQLearner
from hrl_torch.modules.exploration import linear_epsilon
from hrl_torch.modules.schedules import Schedule
from hrl_torch.multiagent.cooperative import Cooperation, MultiAgentConfig, cooperative_graph
from hrl_torch.runs.domain import AlgoSpec, DomainSpec
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.continuing import ThroughputEvaluator

ROOT_STATES = 2**N_JOBS
NAV_STATES = N_LOCATIONS
_SUCC = successors()  # [location, move] -> next location
NAV_TARGETS = {
    **{f"W_{i + 1}": BAYS[i] for i in range(N_STATIONS)},
    **{f"D_{i + 1}": DROP_OFF[i] for i in range(N_STATIONS)},
    **{f"P_{i + 1}": PICK_UP[i] for i in range(N_STATIONS)},
    "WA": WAREHOUSE_DROP,
}


def dm_states(capacity: int = CAPACITY) -> int:
    """Abstract states of ``DM_i``: ``100 x 9 x (c + 1) x 2`` (7,200 for ``c = 3``)."""
    return N_LOCATIONS * N_STATUS * (capacity + 1) * 2


def da_states(capacity: int = CAPACITY) -> int:
    """Abstract states of ``DA_i``: ``100 x 9 x (c + 1)`` (3,600 for ``c = 3``)."""
    return N_LOCATIONS * N_STATUS * (capacity + 1)


class Navigate(Subtask):
    """``Nav_t``: drive to location ``t`` with the moves; abstraction: location."""

    def __init__(self, target: str) -> None:
        super().__init__(f"Nav_{target}", ["Forward", "Left", "Right"], n_states=NAV_STATES)
        self.target = NAV_TARGETS[target]

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        """The AGV's location."""
        return obs["location"]

    def terminated(self, obs: TensorDict) -> torch.Tensor:
        """At the target."""
        return obs["location"] == self.target

    def child_mask(self, obs: TensorDict) -> torch.Tensor:
        """The moves that move (a turn away from a branch would do nothing)."""
        loc = obs["location"]
        return constant_on(_SUCC, loc.device)[loc] != loc[:, None]

    def shaping_reward(self, obs: TensorDict, action, next_obs: TensorDict) -> torch.Tensor:
        """-1 per move: an internal cost (see ``step_cost``)."""
        return step_cost(obs, action, next_obs)


def step_cost(obs: TensorDict, action, next_obs: TensorDict) -> torch.Tensor:
    """An internal reward of -1 per primitive step inside ``Nav_t``, ``DM_i`` and ``DA_i``.

    With 1 ms moves a route's length costs almost no time, so time discounting alone does not
    teach the shortest path; the internal cost does, inside the subtask only (MAXQ's internal
    completions choose; the external values the root reads stay the deliveries' discounted
    rewards, Section 3.1).
    """
    return -torch.ones(action.shape[0], device=action.device)


def station_fields(obs: TensorDict, name: str) -> torch.Tensor:
    """``[B, 4]``: the fields ``name_1 .. name_4``."""
    return torch.stack([obs[f"{name}_{k}"] for k in range(1, N_STATIONS + 1)], -1)


def job_available(obs: TensorDict, capacity: int = CAPACITY) -> torch.Tensor:
    """``[B, 8]`` bool: which of ``DM_1..4, DA_1..4`` an empty AGV can start now."""
    material = (station_fields(obs, "warehouse") > 0) & (station_fields(obs, "drop_off") < capacity)
    return torch.cat([material, station_fields(obs, "pick_up") > 0], -1)


def root_abstract(obs: TensorDict, capacity: int = CAPACITY) -> torch.Tensor:
    """Root state: bit ``k`` says job ``k`` (``DM_1..4, DA_1..4``) can start; in ``[0, 256)``."""
    weights = 2 ** torch.arange(N_JOBS, device=obs.device)
    return (job_available(obs, capacity).long() * weights).sum(-1)


def _deliver_material(i: int, capacity: int) -> Subtask:
    """``DM_i`` (``i`` 0-based): load part ``i`` at its bay, unload it at ``Di``."""
    k = i + 1
    d, w = f"drop_off_{k}", f"warehouse_{k}"
    levels = capacity + 1

    def abstract(o):
        return ((o["location"] * N_STATUS + o["status"]) * levels + o[d]) * 2 + o[w]

    def initiable(o):
        s = o["status"]
        return ((s == EMPTY) & (o[w] > 0) & (o[d] < capacity)) | (s == k)

    def terminated(o):
        s = o["status"]
        gone = (s == EMPTY) & ((o[w] == 0) | (o[d] >= capacity))
        return (o["delivery"] == k) | ((s != EMPTY) & (s != k)) | gone

    def child_mask(o):  # a load or unload only where it applies (else it does nothing)
        empty, full = o["status"] == EMPTY, o[d] >= capacity
        at_bay, at_drop = o["location"] == BAYS[i], o["location"] == DROP_OFF[i]
        return torch.stack(
            [
                empty & ~at_bay,
                empty & at_bay,
                ~empty & ~at_drop,
                ~empty & at_drop & ~full,
                ~empty & at_drop & full,
            ],
            -1,
        )

    return Subtask(
        f"DM_{k}",
        [f"Nav_W_{k}", "Load", f"Nav_D_{k}", "Unload", "Idle"],
        n_states=dm_states(capacity),
        abstract=abstract,
        initiable=initiable,
        terminated=terminated,
        child_mask=child_mask,
        event_termination=True,
        shaping_reward=step_cost,
    )


def _deliver_assembly(i: int, capacity: int) -> Subtask:
    """``DA_i`` (``i`` 0-based): load assembly ``i`` at ``Pi``, unload it at ``WA``."""
    k, asm = i + 1, N_STATIONS + i + 1
    p = f"pick_up_{k}"

    def abstract(o):
        return (o["location"] * N_STATUS + o["status"]) * (capacity + 1) + o[p]

    def initiable(o):
        s = o["status"]
        return ((s == EMPTY) & (o[p] > 0)) | (s == asm)

    def terminated(o):
        s = o["status"]
        gone = (s == EMPTY) & (o[p] == 0)
        return (o["delivery"] == asm) | ((s != EMPTY) & (s != asm)) | gone

    def child_mask(o):  # a load or unload only where it applies (else it does nothing)
        empty = o["status"] == EMPTY
        at_pick, at_drop = o["location"] == PICK_UP[i], o["location"] == WAREHOUSE_DROP
        return torch.stack(
            [empty & ~at_pick, empty & at_pick, ~empty & ~at_drop, ~empty & at_drop], -1
        )

    return Subtask(
        f"DA_{k}",
        [f"Nav_P_{k}", "Load", "Nav_WA", "Unload"],
        n_states=da_states(capacity),
        abstract=abstract,
        initiable=initiable,
        terminated=terminated,
        child_mask=child_mask,
        event_termination=True,
        shaping_reward=step_cost,
    )


def primitives() -> list[Primitive]:
    """The six primitive actions; only ``Unload``'s reward depends on the state."""
    return [
        Primitive("Forward", FORWARD),
        Primitive("Left", LEFT),
        Primitive("Right", RIGHT),
        Primitive("Load", LOAD),
        Primitive(
            "Unload",
            UNLOAD,
            N_LOCATIONS * N_STATUS,
            lambda o: o["location"] * N_STATUS + o["status"],
        ),
        Primitive("Idle", IDLE),
    ]


def four_agv_hierarchy(capacity: int = CAPACITY) -> TaskGraph:
    """The task graph of Figure 6.3 with the abstractions of the module docstring.

    Args:
        capacity: the env's buffer capacity (3 in the text, 1 for Figure 6.6).
    """
    dm = [_deliver_material(i, capacity) for i in range(N_STATIONS)]
    da = [_deliver_assembly(i, capacity) for i in range(N_STATIONS)]
    navs = [Navigate(t) for t in NAV_TARGETS]
    root = Subtask(
        "Root",
        [*(x.name for x in dm + da), "Idle"],
        n_states=ROOT_STATES,
        abstract=lambda o: root_abstract(o, capacity),
    )
    return TaskGraph("Root", [root, *dm, *da, *navs, *primitives()], n_actions=N_ACTIONS)


def flat_graph(capacity: int = 1) -> TaskGraph:
    """One root over the primitives on the agent's flat state (the flat Q-learner, Figure 6.6).

    The abstraction is the env's per-agent ``observation``: ``100 x 9 x (c + 1)**8 x 2**4``
    states, 3,686,400 with the capacity 1 of Figure 6.6 (943,718,400 with 3: too many for a
    table).
    """
    root = Subtask(
        "Root",
        [p.name for p in primitives()],
        n_states=n_flat_states(capacity),
        abstract=lambda o: o["observation"],
    )
    return TaskGraph("Root", [root, *primitives()], n_actions=N_ACTIONS)


# ---------------------------------------------------------------------- experiments (Ch. 6)
#: discount per second of the multi-agent learners (jobs pay off one assembly, 15-30 s, later)
GAMMA = 0.97
COOPERATION = Cooperation((("Root",),), idle="Idle")
#: cooperation at the root and at the navigation level (Figure 6.8)
NAV_COOPERATION = Cooperation((("Root",), tuple(f"Nav_{t}" for t in NAV_TARGETS)), idle="Idle")


def make_env(
    seeds,
    envs_per_learner: int,
    backend: str = "torch",
    n_agents: int = 4,
    capacity: int = CAPACITY,
    timing: FourAGVTiming = TABLE_6_1,
) -> FourAGVEnv:
    """The four-AGV task (or ``n_agents`` AGVs) for ``seeds``.

    Each AGV learns from its own deliveries (``own_rewards``; their sum is the team's).
    """
    return FourAGVEnv(seeds, envs_per_learner, n_agents, capacity, timing, own_rewards=True)


def throughput_evaluator(config: TrainConfig) -> ThroughputEvaluator:
    """Assemblies delivered per 1,000 s, greedy (500 s after 50 s) and in training.

    The training throughput is the text's curves.
    """
    return ThroughputEvaluator(
        horizon_time=500.0,
        burn_in_time=50.0,
        max_steps=20_000,
        scale=1_000.0,
        unit="assemblies per 1,000 s",
    )


#: moves round the outer loop, the longest route (``envs.four_agv``)
LONGEST_ROUTE = 50


def internal_init(timing: FourAGVTiming = TABLE_6_1, gamma: float = GAMMA) -> float:
    """Initial internal completions: the discounted step cost of the longest route.

    Internal completions (step costs inside Nav/DM/DA) start pessimistic: with 0 the greedy
    policy prefers untried moves and loops where exploration did not go. But not below the
    value of moving round in circles forever, ``-1 / (1 - GAMMA**tau)``: then every move that
    has been tried, a loop included, looks better than one that has not. With 1 ms moves that
    bound is far away (-32,831) and the init is about -50; with the 2 s moves of Figure 6.5 it
    is -16.9, and an init of -50 kept the AGVs circling the loops with their loads (the
    untried turn into a branch stayed below the tried ``Forward``): there the init is -16.1.
    """
    per_move = gamma**timing.action_mean
    return -sum(per_move**k for k in range(LONGEST_ROUTE))


def maxq_learner(
    graph: TaskGraph,
    sets: int,
    timing: FourAGVTiming = TABLE_6_1,
    alpha: float | Schedule = 0.2,
    gamma: float = GAMMA,
) -> MaxQLearner:
    """MAXQ-Q for the primitives' ``timing`` (``internal_init``), step size ``alpha``.

    The step-cost pessimism reaches only the subtasks with step costs (``Nav_t``, ``DM_i``,
    ``DA_i``); the root starts at 0 (``MaxQLearner``'s ``init_internal``; docs/defaults.md,
    "The discount trap").
    """
    init = internal_init(timing, gamma)
    return MaxQLearner(graph, sets, alpha=alpha, gamma=gamma, init_internal=init)


def _maxq(timing: FourAGVTiming = TABLE_6_1) -> Make:
    return Make(maxq_learner, timing=timing, alpha=0.2)


def rule_learner(graph: TaskGraph, sets: int, rule: str, n_agents: int = 4) -> RuleLearner:
    """The dispatching rule ``DISPATCH_RULES[rule]`` for ``n_agents`` AGVs per row group."""
    cls = DISPATCH_RULES[rule]
    return RuleLearner(graph, sets, lambda rows: cls(rows // n_agents, n_agents))


#: a job or a route that takes 2,000 moves is lost: abort it (no learning target) and go on
GUARD = ExecutorConfig(max_subtask_steps=2_000, on_timeout="abort")
TRAIN = TrainConfig(steps=200_000, eval_every=0, eval_episodes=4, log_every=5_000)


def algo_spec(make_graph, learner, description, multiagent=None, **env_options) -> AlgoSpec:
    """One four-AGV algorithm: the budget, exploration, guard and rows every reading shares."""
    return AlgoSpec(
        make_graph=make_graph,
        learner=learner,
        exploration=linear_epsilon(0.3, 0.02, Fraction(1, 2)),
        train=TRAIN,
        envs_per_learner=32,
        executor=GUARD,
        description=description,
        multiagent=multiagent,
        env_options=env_options,
    )


def _algos() -> dict[str, AlgoSpec]:
    spec = algo_spec
    joint = MultiAgentConfig(COOPERATION)
    joint_nav = MultiAgentConfig(NAV_COOPERATION)
    algos = {
        "cooperative": spec(
            lambda: cooperative_graph(four_agv_hierarchy(), COOPERATION, 4),
            _maxq(),
            "Cooperative HRL: joint completions at the root (Algorithm 4)",
            joint,
        ),
        "cooperative-nav": spec(
            lambda: cooperative_graph(four_agv_hierarchy(), NAV_COOPERATION, 4),
            _maxq(),
            "Cooperative HRL at the root and the navigation level (Figure 6.8)",
            joint_nav,
        ),
        "selfish": spec(
            four_agv_hierarchy, _maxq(), "selfish multi-agent HRL: each agent learns alone"
        ),
        "single": spec(four_agv_hierarchy, _maxq(), "single-agent HRL: one AGV", n_agents=1),
        # Figure 6.5: 2 s primitive actions (the learner's init depends on the timing)
        "cooperative-2s": spec(
            lambda: cooperative_graph(four_agv_hierarchy(), COOPERATION, 4),
            _maxq(FIGURE_6_5),
            "Cooperative HRL, 2 s primitive actions (Figure 6.5)",
            joint,
            timing=FIGURE_6_5,
        ),
        "selfish-2s": spec(
            four_agv_hierarchy,
            _maxq(FIGURE_6_5),
            "selfish multi-agent HRL, 2 s primitive actions (Figure 6.5)",
            timing=FIGURE_6_5,
        ),
        # Figure 6.6: the graph's masks, initiation and root state read the capacity too
        "single-c1": spec(
            lambda: four_agv_hierarchy(1),
            _maxq(),
            "single-agent HRL, one AGV, buffer capacity 1 (Figure 6.6)",
            n_agents=1,
            capacity=1,
        ),
        "q": spec(
            lambda: flat_graph(1),
            Make(SMDPQLearner, alpha=0.2, gamma=GAMMA),
            "flat Q-learning, one AGV, buffer capacity 1 (Figure 6.6)",
            n_agents=1,
            capacity=1,
        ),
    }
    for name, cls in DISPATCH_RULES.items():
        algos[name] = spec(
            lambda: flat_graph(CAPACITY),
            Make(rule_learner, rule=name),
            f"dispatching rule: {cls.name}",
        )
    return algos


DOMAIN = DomainSpec(
    name="four-agv-earlier",
    description="four-AGV scheduling, the reading before Section 6.4's (kept for comparison)",
    make_env=make_env,
    algos=_algos(),
    make_evaluator=throughput_evaluator,
)
