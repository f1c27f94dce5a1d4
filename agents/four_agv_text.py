"""The four-AGV task as Section 6.4 describes it: committed jobs, waiting, a team reward.

The ``four-agv`` domain; ``four-agv-earlier`` (``agents/four_agv.py``) is the earlier reading, kept
for comparison. The env is the same ``FourAGVEnv`` (Figure 6.2, Table 6.1); what differs:

* **Committed jobs.** ``DM_i`` may start whenever the AGV is empty and ``Di`` has room,
  ``DA_i`` whenever it is empty and an assembly waits in ``Pi`` or is on its way (a part in
  ``Di``). Each ends only when its item is delivered into ``Di`` (at ``WA``), except a
  ``DA_i`` whose assembly can no longer come (``Pi`` and ``Di`` both empty). A lost race is
  not the end: an AGV that finds its bay ``Wi`` (its ``Pi``) empty, or ``Di`` full with part
  ``i`` on board, waits there (``Idle``, 1 s at a time, time passes) until it can load
  (unload). This is the text's "once the first agent completes the task, the other agents
  might have to wait for a long time to complete the task, due to the constraints on the
  number of parts that can be stored" (after Table 6.1). The limits keep four AGVs from
  waiting for each other for ever: with ``DM_i`` open to an empty AGV at a full ``Di``,
  Cooperative HRL's training throughput with 1 ms moves ended at 0 in both seeds of a trial
  run (before, with ``DA_i`` open when nothing could come, selfish HRL's with 2 s moves fell
  to 0 too).
* **The root sees buffer levels** (as the root of Chapter 4's AGV task does), not which jobs
  can start: per station ``i``, whether part ``i`` can go now (it waits in ``Wi`` and ``Di``
  has room) and the level of ``Pi`` (empty, partly full, full: the machine is blocked), 6
  values, ``6**4 = 1,296`` states. The full levels (``4**8 x 2**4``, about 10**6 states)
  would make Cooperative HRL's joint root table ``10**6 x 9**3 x 8`` entries per agent; this
  one is ``1,296 x 729 x 8 = 7.6 M``. The root's children are the text's ``U_1 = {DM_1..4,
  DA_1..4}``, no ``Idle``: an AGV waits inside its job. (With ``Idle`` at the root and the
  team reward, idling looked as good as working: the team's deliveries pay the idler too,
  and 2 s selfish agents delivered 0-6 assemblies per 1,000 s greedy in trials; without it,
  26.) ``DM_i`` keeps ``100 x 9 x 4 x 2`` states (location, status, ``Di``, ``Wi``) and
  ``DA_i`` ``100 x 9 x 4`` (location, status, ``Pi``), the text's counts, which are exactly
  what their wait-or-act choices need.
* **Rewards.** The env's default is one team reward (every agent receives the team's
  assemblies). The registered 1 ms learners (``cooperative``, ``selfish``, ``single``) use
  issue 33's measured settings instead (``SETTLING``, ``GAMMA_1MS``, ``OWN_DELIVERIES``):
  each AGV is paid for its own deliveries, 1 per part dropped at its workstation and 1 per
  assembly brought back (in the long run parts and assemblies come at the same rate, so the
  gain is twice the throughput for every policy), per-entry step sizes ``max(1/n, 0.2)`` and
  a discount of 0.8 per second. With them selfish HRL went from 55.0 to 158.8 (2 seeds,
  docs/reproduction.md); the ``-2s`` learners keep the team reward, 0.2 and 0.97.
* **Per-AGV dispatching rules** (Figure 6.7): each vehicle applies FCFS / HQF / NSF to its
  own view, with no reservations and no knowledge of the other vehicles' jobs, and commits to
  the job it picked until the delivery (``PerAGVRule``; like ``DA_i`` it drops a fetch whose
  assembly can no longer come). The centralised dispatchers of
  ``agents/four_agv.py`` (claims and reserved slots) coordinate the vehicles; these do not.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from agents.four_agv import (
    NAV_TARGETS,
    Navigate,
    algo_spec,
    da_states,
    dm_states,
    flat_graph,
    maxq_learner,
    primitives,
    station_fields,
    step_cost,
)
from agents.four_agv_rules import DISPATCH_RULES, NO_JOB, lexicographic_argmax
from envs.agv import AGVRewards
from envs.four_agv import (
    BAYS,
    CAPACITY,
    DROP_OFF,
    EMPTY,
    FIGURE_6_5,
    IDLE,
    LOAD,
    N_ACTIONS,
    N_STATIONS,
    PICK_UP,
    TABLE_6_1,
    UNLOAD,
    WAREHOUSE_DROP,
    FourAGVEnv,
    FourAGVTiming,
)
from hrl_torch.common.config import Make
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Subtask
from hrl_torch.learners import RuleLearner
from hrl_torch.modules.schedules import Linear, VisitCount
from hrl_torch.multiagent.cooperative import Cooperation, MultiAgentConfig, cooperative_graph
from hrl_torch.runs.domain import AlgoSpec, DomainSpec
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.continuing import ThroughputEvaluator

#: values per station in the root state: (part ready 0/1) x (Pi empty / partly full / full)
STATION_CODES = 6
ROOT_STATES = STATION_CODES**N_STATIONS
#: Cooperative HRL at the root; ``U_1`` has no ``Idle``: an agent without a job (only at a
#: reset) gets a code of its own (8 jobs + 1 values per other agent, as with ``Idle``)
COOPERATION = Cooperation((("Root",),))


def root_abstract(obs: TensorDict, capacity: int = CAPACITY, levels: int = 3) -> torch.Tensor:
    """Root state in ``[0, (2 levels)^4)``: per station, part ready x level of ``Pi``.

    ``levels`` 3 (the registered root, 1,296 states): ``Pi`` empty / partly full / full; 2 (a
    smaller root, 256 states): empty / not.
    """
    ready = (station_fields(obs, "warehouse") > 0) & (station_fields(obs, "drop_off") < capacity)
    pick = station_fields(obs, "pick_up")
    level = (pick > 0).long()  # 0 empty, 1 not (levels 2) or partly full, 2 full (levels 3)
    if levels == 3:
        level = level + (pick >= capacity).long()
    code = ready.long() * levels + level
    weights = (2 * levels) ** torch.arange(N_STATIONS, device=code.device)
    return (code * weights).sum(-1)


def _deliver_material(i: int, capacity: int) -> Subtask:
    """Committed ``DM_i`` (``i`` 0-based): fetch part ``i`` at ``Wi`` and unload it at ``Di``.

    Waits (``Idle``) at an empty bay and at a full ``Di``; ends only on the delivery.
    """
    k = i + 1
    d, w = f"drop_off_{k}", f"warehouse_{k}"
    levels = capacity + 1

    def abstract(o):
        return ((o["location"] * 9 + o["status"]) * levels + o[d]) * 2 + o[w]

    def initiable(o):  # empty with room in Di now (a lost race may still find it full)
        return ((o["status"] == EMPTY) & (o[d] < capacity)) | (o["status"] == k)

    def terminated(o):
        s = o["status"]
        return (o["delivery"] == k) | ((s != EMPTY) & (s != k))

    def child_mask(o):  # Nav_W, Load, Nav_D, Unload, Idle (wait at the bay or at Di)
        empty, full, has_part = o["status"] == EMPTY, o[d] >= capacity, o[w] > 0
        at_bay, at_drop = o["location"] == BAYS[i], o["location"] == DROP_OFF[i]
        wait = (empty & at_bay & ~has_part) | (~empty & at_drop & full)
        load, unload = empty & at_bay & has_part, ~empty & at_drop & ~full
        return torch.stack([empty & ~at_bay, load, ~empty & ~at_drop, unload, wait], -1)

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
    """Committed ``DA_i``: fetch assembly ``i`` at ``Pi``, unload it at ``WA``.

    Waits (``Idle``) at an empty ``Pi``; ends only on the delivery.
    """
    k, asm = i + 1, N_STATIONS + i + 1
    p, d = f"pick_up_{k}", f"drop_off_{k}"

    def abstract(o):
        return (o["location"] * 9 + o["status"]) * (capacity + 1) + o[p]

    def initiable(o):  # an assembly waits, or one is on its way (a part in Di)
        coming = (o[p] > 0) | (o[d] > 0)
        return ((o["status"] == EMPTY) & coming) | (o["status"] == asm)

    def terminated(o):  # delivered, or nothing left to come (no assembly, no part in Di)
        s = o["status"]
        gone = (s == EMPTY) & (o[p] == 0) & (o[d] == 0)
        return (o["delivery"] == asm) | ((s != EMPTY) & (s != asm)) | gone

    def child_mask(o):  # Nav_P, Load, Nav_WA, Unload, Idle (wait at an empty Pi)
        empty, has = o["status"] == EMPTY, o[p] > 0
        at_pick, at_drop = o["location"] == PICK_UP[i], o["location"] == WAREHOUSE_DROP
        return torch.stack(
            [
                empty & ~at_pick,
                empty & at_pick & has,
                ~empty & ~at_drop,
                ~empty & at_drop,
                empty & at_pick & ~has,
            ],
            -1,
        )

    return Subtask(
        f"DA_{k}",
        [f"Nav_P_{k}", "Load", "Nav_WA", "Unload", "Idle"],
        n_states=da_states(capacity),
        abstract=abstract,
        initiable=initiable,
        terminated=terminated,
        child_mask=child_mask,
        event_termination=True,
        shaping_reward=step_cost,
    )


def text_hierarchy(
    capacity: int = CAPACITY, root_levels: int = 3, root_idle: bool = False
) -> TaskGraph:
    """Figure 6.3 with committed, waiting jobs and the buffer-level root (module docstring).

    The root's children are ``U_1 = {DM_1..4, DA_1..4}`` (the text's list; no ``Idle``: an AGV
    waits inside its job). Some job is always initiable: ``DM_i`` whenever the AGV is empty,
    the job it carries for otherwise. ``root_levels`` 2: the smaller root (``root_abstract``).
    ``root_idle``: the root may also choose ``Idle`` (1 s, then it chooses again), which
    commits the AGV to nothing, as the per-AGV rules wait (issue 33's untried list).
    """
    if root_levels not in (2, 3):
        raise ValueError(f"root_levels must be 2 or 3, got {root_levels}")
    dm = [_deliver_material(i, capacity) for i in range(N_STATIONS)]
    da = [_deliver_assembly(i, capacity) for i in range(N_STATIONS)]
    navs = [Navigate(t) for t in NAV_TARGETS]
    root = Subtask(
        "Root",
        [x.name for x in dm + da] + (["Idle"] if root_idle else []),
        n_states=(2 * root_levels) ** N_STATIONS,
        abstract=lambda o: root_abstract(o, capacity, root_levels),
    )
    return TaskGraph("Root", [root, *dm, *da, *navs, *primitives()], n_actions=N_ACTIONS)


# ---------------------------------------------------------------------- per-AGV rules (Fig 6.7)
class PerAGVRule:
    """A dispatching rule applied by each vehicle on its own: no claims, no reservations.

    An empty AGV without a job takes, when it acts, the best job by the rule's keys among those
    with an item waiting (``DM_i``: part ``i`` in ``Wi`` and room in ``Di``; ``DA_i``: an
    assembly in ``Pi``), judged from its own location, blind to what the other AGVs have taken;
    several AGVs may take the same job. It keeps the job until its delivery: it drives by the
    shortest path, loads when the item is there and otherwise waits (``Idle``); loaded, it
    drives to ``Di`` (``WA``) and unloads, waiting while ``Di`` is full. (As ``DA_i``, it drops
    a fetch at ``Pi`` whose assembly can no longer come: ``Pi`` and ``Di`` both empty.)

    Args:
        rule: the centralised rule whose ``keys`` it uses (``DISPATCH_RULES``).
        batch_size: env rows ``B``.
        n_agents: agents per row.
        capacity: the env's buffer capacity.
    """

    def __init__(self, rule: str, batch_size: int, n_agents: int, capacity: int = CAPACITY):
        self.base = DISPATCH_RULES[rule](batch_size, n_agents, capacity)
        self.name = f"per-AGV {self.base.name}"
        self.capacity = int(capacity)

    @property
    def job(self) -> torch.Tensor:
        """``[B, n]``: each AGV's job (``NO_JOB`` or 0..7)."""
        return self.base.job

    def reset(self) -> None:
        """Forget every job."""
        self.base.reset()

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The per-agent memory."""
        return self.base.state_dict()

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore ``state_dict``."""
        self.base.load_state_dict(state)

    def __call__(self, td: TensorDict) -> torch.Tensor:
        """Primitive actions ``[B * n]`` for the agent rows ``td``."""
        b, n = self.base.job.shape
        cap, base = self.capacity, self.base

        def per_agent(key: str) -> torch.Tensor:
            return td[key].view(b, n)

        def shared(key: str) -> torch.Tensor:
            value = td[key]
            return value.view(b, n, *value.shape[1:])[:, 0]

        loc, status, acting = per_agent("location"), per_agent("status"), per_agent("acting")
        drop = torch.stack([shared(f"drop_off_{k}") for k in range(1, N_STATIONS + 1)], -1)
        pick = torch.stack([shared(f"pick_up_{k}") for k in range(1, N_STATIONS + 1)], -1)
        bays = torch.stack([shared(f"warehouse_{k}") for k in range(1, N_STATIONS + 1)], -1)
        waiting = torch.cat([bays, pick], -1)  # [B, 8] items at the load locations
        age = torch.cat([shared("bay_age"), shared("pick_up_age")[:, :, 0]], -1)
        empty = status == EMPTY

        # 1. a job lasts from the choice to its delivery (or a reset)
        done = shared("is_init")[:, None] | (per_agent("delivery") > 0)
        job = torch.where(done & acting, NO_JOB, base.job)
        job = torch.where(empty, job, status - 1)  # loaded: the job is what it carries
        station = (job - N_STATIONS).clamp(0, N_STATIONS - 1)
        nothing = (pick.gather(1, station) == 0) & (drop.gather(1, station) == 0)
        job = torch.where(empty & (job >= N_STATIONS) & nothing, NO_JOB, job)  # cannot come

        # 2. each free acting AGV takes the best job with an item waiting, on its own view
        open_ = (waiting > 0) & torch.cat([drop < cap, torch.ones_like(drop, dtype=torch.bool)], -1)
        distance = base.dist[loc][:, :, base.load_at].float()  # [B, n, 8]
        rows = b * n
        primary, second = base.keys(
            waiting[:, None].expand(b, n, -1).reshape(rows, -1).float(),
            age[:, None].expand(b, n, -1).reshape(rows, -1),
            distance.reshape(rows, -1),
        )
        allowed = open_[:, None].expand(b, n, -1).reshape(rows, -1)
        best = lexicographic_argmax(allowed, primary, second).view(b, n)
        job = torch.where(acting & empty & (job == NO_JOB), best, job)
        base.job = job

        # 3. drive; at the target act if possible, else wait
        target = torch.where(empty, base.load_at[job.clamp_min(0)], base.deliver_at[status])
        item_here = waiting.gather(1, job.clamp_min(0)) > 0
        part = (status >= 1) & (status <= N_STATIONS)
        room = drop.gather(1, (status - 1).clamp(0, N_STATIONS - 1)) < cap
        here = torch.where(
            empty,
            torch.where(item_here, LOAD, IDLE),
            torch.where(part & ~room, IDLE, UNLOAD),
        )
        action = torch.where(loc == target, here, base.first[loc, target])
        action = torch.where(empty & (job == NO_JOB), IDLE, action)
        return action.reshape(-1)


# ---------------------------------------------------------------------- experiments
def make_env(
    seeds,
    envs_per_learner: int,
    backend: str = "torch",
    n_agents: int = 4,
    capacity: int = CAPACITY,
    timing: FourAGVTiming = TABLE_6_1,
    own_rewards: bool = False,
    part_reward: float = 0.0,
) -> FourAGVEnv:
    """The four-AGV task with the team reward: every agent receives the team's assemblies.

    ``own_rewards``: each agent is paid for its own deliveries instead (their sum is the
    team's; issue 33's untried list, measured in docs/reproduction.md). ``part_reward``: also
    this much per part dropped at its workstation (``AGVRewards.part``). Every part dropped
    into ``Di`` becomes one assembly (machines never discard), so in the long run parts and
    assemblies come at the same rate and the gain is ``(1 + part_reward)`` times the
    throughput: the average-reward optimal policies stay the same.
    """
    rewards = AGVRewards(part=part_reward)
    return FourAGVEnv(
        seeds, envs_per_learner, n_agents, capacity, timing, rewards, own_rewards=own_rewards
    )


def assemblies(td: TensorDict) -> torch.Tensor:
    """The step's assemblies delivered ``[B]`` (the throughput's count, whatever the reward)."""
    return td["assemblies_delivered"]


def throughput_evaluator(config: TrainConfig) -> ThroughputEvaluator:
    """Team assemblies per 1,000 s: greedy in ``[200, 1200)`` s of a fresh system; in training.

    Longer than ``four-agv-earlier``'s window (``[50, 550)`` s): with committed jobs and 2 s moves
    the system needs a few hundred seconds to fill its buffers.
    """
    return ThroughputEvaluator(
        horizon_time=1_000.0,
        burn_in_time=200.0,
        max_steps=60_000,
        metric=assemblies,
        scale=1_000.0,
        unit="assemblies per 1,000 s",
    )


def per_agv_rule_learner(graph: TaskGraph, sets: int, rule: str, n_agents: int = 4):
    """The per-AGV rule ``rule`` for ``n_agents`` AGVs per row group."""
    return RuleLearner(graph, sets, lambda rows: PerAGVRule(rule, rows // n_agents, n_agents))


def _per_agv_rule(name: str) -> Make:
    return Make(per_agv_rule_learner, rule=name)


def _maxq(
    timing: FourAGVTiming = TABLE_6_1,
    alpha: float | Linear | VisitCount = 0.2,
    gamma: float | None = None,
) -> Make:
    """MAXQ-Q for the primitives' ``timing`` (``internal_init``), step size ``alpha``.

    ``gamma``: the discount per second (``None``: ``maxq_learner``'s, ``GAMMA``).
    """
    extra = {} if gamma is None else {"gamma": gamma}
    return Make(maxq_learner, timing=timing, alpha=alpha, **extra)


#: issue 33's measured changes for 1 ms moves (docs/reproduction.md, "one change at a time"):
#: a per-entry step size that settles, 0.8 per second, each AGV paid for its own deliveries,
#: parts as well as assemblies (the same long-run rate: ``make_env``)
SETTLING = VisitCount(0.2)
GAMMA_1MS = 0.8
OWN_DELIVERIES = {"own_rewards": True, "part_reward": 1.0}


def _algos() -> dict[str, AlgoSpec]:
    spec = algo_spec  # the earlier reading's budget, exploration and guard
    joint = MultiAgentConfig(COOPERATION)

    def coop():
        return cooperative_graph(text_hierarchy(), COOPERATION, 4)

    slow = {"timing": FIGURE_6_5}
    fast = _maxq(alpha=SETTLING, gamma=GAMMA_1MS)
    algos = {
        "cooperative": spec(
            coop, fast, "Cooperative HRL, own deliveries (Algorithm 4)", joint, **OWN_DELIVERIES
        ),
        "selfish": spec(
            text_hierarchy, fast, "selfish multi-agent HRL, own deliveries", **OWN_DELIVERIES
        ),
        "single": spec(
            text_hierarchy, fast, "single-agent HRL: one AGV", n_agents=1, **OWN_DELIVERIES
        ),
        "cooperative-2s": spec(
            coop, _maxq(FIGURE_6_5), "Cooperative HRL, 2 s primitives (Figure 6.5)", joint, **slow
        ),
        "selfish-2s": spec(
            text_hierarchy, _maxq(FIGURE_6_5), "selfish HRL, 2 s primitives (Figure 6.5)", **slow
        ),
        "single-2s": spec(
            text_hierarchy,
            _maxq(FIGURE_6_5),
            "single-agent HRL, 2 s primitives",
            n_agents=1,
            **slow,
        ),
    }
    for name, cls in DISPATCH_RULES.items():
        algos[name] = spec(
            lambda: flat_graph(CAPACITY), _per_agv_rule(name), f"per-AGV rule: {cls.name}"
        )
        algos[f"{name}-2s"] = spec(
            lambda: flat_graph(CAPACITY),
            _per_agv_rule(name),
            f"per-AGV rule: {cls.name}, 2 s primitives",
            **slow,
        )
    return algos


DOMAIN = DomainSpec(
    name="four-agv",
    description="four-AGV scheduling as Section 6.4 reads: committed waiting jobs, team reward",
    make_env=make_env,
    algos=_algos(),
    make_evaluator=throughput_evaluator,
)
