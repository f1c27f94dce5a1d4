"""The AGV task graph of Figure 4.5, the flat graph for RVI Q-learning and a dispatching rule.

Task graph (reconstructed from Section 4.3.2)::

    Root ─┬─ DM_i ─┬─ Nav_W_i ─┐                  i = 1..3: deliver material to Mi
          │        ├─ Nav_D_i ─┤
          │        └─ Load, Unload
          ├─ DA_i ─┬─ Nav_P_i ─┼─ Forward, Turn   i = 1..3: deliver assembly from Mi
          │        ├─ Nav_WA ──┘                  (Nav_WA shared by DA_1..3)
          │        └─ Load, Unload
          └─ Idle

``Nav_t`` is one subtask per target location ``t`` (Dietterich's ``Navigate(t)``). The status
binds the children: an empty AGV may only call ``Nav_W_i``/``Nav_P_i`` and ``Load``, a loaded
one only ``Nav_D_i``/``Nav_WA`` and ``Unload`` (``child_mask``). State abstractions:

=========  ===========================================================  =========
node       relevant variables                                           states
=========  ===========================================================  =========
Root       location, drop_off_1..3, pick_up_1..3, warehouse_1..3        192,456
DM_i       location, status, drop_off_i, warehouse_i                    1,386
DA_i       location, status, pick_up_i                                  693
Nav_t      location                                                     33
Unload     location, status (its reward depends on them)                231
others     none                                                         1
=========  ===========================================================  =========

The text's counts fix DM_i at ``33 x 7 x 3 x 2`` and DA_i at ``33 x 7 x 3``. Root is not given;
it omits the AGV status because the root only decides with an empty AGV (DM/DA end on an
unload, and the AGV starts empty).

Initiation and termination (``delivery`` is the env's per-step "what was just delivered"):

* ``DM_i``: initiable when the AGV is empty, part ``i`` waits in the warehouse and ``Di`` has
  room, or when it carries part ``i``; terminates when part ``i`` is delivered into ``Di``
  (``delivery == i``), when the AGV carries anything else, or when it is empty and part ``i``
  is gone or ``Di`` is full (another AGV got there first: multi-AGV only).
* ``DA_i``: initiable when the AGV is empty and ``Pi`` holds an assembly, or when it carries
  assembly ``i``; terminates when assembly ``i`` is delivered (``delivery == 3 + i``), when
  the AGV carries anything else, or when it is empty and ``Pi`` is empty.
* ``Nav_t``: terminates at ``t``.

Because termination is read from the last step, ``DM_i`` (``DA_i``) cannot be chosen again at
the very decision after it delivered: the root picks another child or ``Idle`` first.
"""

from __future__ import annotations

from dataclasses import replace
from fractions import Fraction

import torch
from tensordict import TensorDict

from envs.agv import (
    BAYS,
    CAPACITY,
    CONTINUOUS,
    DROP_OFF,
    EMPTY,
    FORWARD,
    IDLE,
    LOAD,
    N_ACTIONS,
    N_LOCATIONS,
    N_STATES,
    N_STATIONS,
    N_STATUS,
    PICK_UP,
    TURN,
    UNLOAD,
    WAREHOUSE_DROP,
    AGVEnv,
    encode,
    shortest_paths,
)
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.modules.exploration import linear_epsilon
from hrl_torch.runs.algorithms import Tasks
from hrl_torch.runs.domain import DomainSpec
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.continuing import ThroughputEvaluator

N_LEVELS = CAPACITY + 1
ROOT_STATES = N_LOCATIONS * N_LEVELS ** (2 * N_STATIONS) * 2**N_STATIONS
DM_STATES = N_LOCATIONS * N_STATUS * N_LEVELS * 2
DA_STATES = N_LOCATIONS * N_STATUS * N_LEVELS
NAV_TARGETS = {
    **{f"W_{i + 1}": BAYS[i] for i in range(N_STATIONS)},
    **{f"D_{i + 1}": DROP_OFF[i] for i in range(N_STATIONS)},
    **{f"P_{i + 1}": PICK_UP[i] for i in range(N_STATIONS)},
    "WA": WAREHOUSE_DROP,
}


class Navigate(Subtask):
    """``Nav_t``: drive to location ``t`` with ``Forward``/``Turn``; abstraction: location."""

    def __init__(self, target: str) -> None:
        super().__init__(f"Nav_{target}", ["Forward", "Turn"], n_states=N_LOCATIONS)
        self.target = NAV_TARGETS[target]

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        """The AGV's location."""
        return obs["location"]

    def terminated(self, obs: TensorDict) -> torch.Tensor:
        """At the target."""
        return obs["location"] == self.target


def _bind(empty_children: int):
    """``child_mask``: the first ``empty_children`` children when empty, the others when loaded."""

    def mask(obs: TensorDict) -> torch.Tensor:
        empty = (obs["status"] == EMPTY)[:, None]
        first = torch.arange(4, device=empty.device)[None, :] < empty_children
        return torch.where(empty, first, ~first)

    return mask


def _deliver_material(i: int) -> Subtask:
    """``DM_i`` (``i`` 0-based): load part ``i`` at its bay, unload it at ``Di``."""
    k = i + 1
    d, w = f"drop_off_{k}", f"warehouse_{k}"

    def abstract(o):
        return ((o["location"] * N_STATUS + o["status"]) * N_LEVELS + o[d]) * 2 + o[w]

    def initiable(o):
        s = o["status"]
        return ((s == EMPTY) & (o[w] > 0) & (o[d] < CAPACITY)) | (s == k)

    def terminated(o):
        s = o["status"]
        gone = (s == EMPTY) & ((o[w] == 0) | (o[d] >= CAPACITY))
        return (o["delivery"] == k) | ((s != EMPTY) & (s != k)) | gone

    return Subtask(
        f"DM_{k}",
        [f"Nav_W_{k}", "Load", f"Nav_D_{k}", "Unload"],
        n_states=DM_STATES,
        abstract=abstract,
        initiable=initiable,
        terminated=terminated,
        child_mask=_bind(2),
    )


def _deliver_assembly(i: int) -> Subtask:
    """``DA_i`` (``i`` 0-based): load assembly ``i`` at ``Pi``, unload it at ``WA``."""
    k, asm = i + 1, N_STATIONS + i + 1
    p = f"pick_up_{k}"

    def abstract(o):
        return (o["location"] * N_STATUS + o["status"]) * N_LEVELS + o[p]

    def initiable(o):
        s = o["status"]
        return ((s == EMPTY) & (o[p] > 0)) | (s == asm)

    def terminated(o):
        s = o["status"]
        gone = (s == EMPTY) & (o[p] == 0)
        return (o["delivery"] == asm) | ((s != EMPTY) & (s != asm)) | gone

    return Subtask(
        f"DA_{k}",
        [f"Nav_P_{k}", "Load", "Nav_WA", "Unload"],
        n_states=DA_STATES,
        abstract=abstract,
        initiable=initiable,
        terminated=terminated,
        child_mask=_bind(2),
    )


def root_abstract(obs: TensorDict) -> torch.Tensor:
    """Root state: location and the nine buffer/warehouse variables, in ``[0, 192_456)``."""
    index = obs["location"]
    for name in ("drop_off", "pick_up"):
        for k in range(1, N_STATIONS + 1):
            index = index * N_LEVELS + obs[f"{name}_{k}"]
    for k in range(1, N_STATIONS + 1):
        index = index * 2 + obs[f"warehouse_{k}"]
    return index


def primitives() -> list[Primitive]:
    """The five primitive actions; only ``Unload``'s reward depends on the state."""
    return [
        Primitive("Forward", FORWARD),
        Primitive("Turn", TURN),
        Primitive("Load", LOAD),
        Primitive(
            "Unload",
            UNLOAD,
            N_LOCATIONS * N_STATUS,
            lambda o: o["location"] * N_STATUS + o["status"],
        ),
        Primitive("Idle", IDLE),
    ]


def agv_hierarchy() -> TaskGraph:
    """The task graph of Figure 4.5 with the abstractions in the module docstring."""
    dm = [_deliver_material(i) for i in range(N_STATIONS)]
    da = [_deliver_assembly(i) for i in range(N_STATIONS)]
    navs = [Navigate(t) for t in NAV_TARGETS]
    root = Subtask(
        "Root", [*(x.name for x in dm + da), "Idle"], n_states=ROOT_STATES, abstract=root_abstract
    )
    return TaskGraph("Root", [root, *dm, *da, *navs, *primitives()], n_actions=N_ACTIONS)


def flat_graph() -> TaskGraph:
    """One root over the primitives, abstraction = the flat state (RVI Q-learning)."""
    root = Subtask(
        "Root",
        [p.name for p in primitives()],
        n_states=N_STATES,
        abstract=lambda o: o["observation"],
    )
    return TaskGraph("Root", [root, *primitives()], n_actions=N_ACTIONS)


def dispatch_action(obs: TensorDict) -> torch.Tensor:
    """A fixed dispatching rule for the flat env (a baseline and a test policy, not an optimum).

    Deliver what the AGV carries; else fetch the nearest waiting assembly; else the nearest
    part whose workstation has room; else ``Idle``. Moves follow shortest paths.

    Returns:
        Actions ``[B]``.
    """
    dist, first = (t.to(obs.device) for t in shortest_paths())
    loc, status, n, dev = obs["location"], obs["status"], N_STATIONS, obs.device
    drop, pick, bays = (torch.tensor(x, device=dev) for x in (DROP_OFF, PICK_UP, BAYS))

    def stack(name: str) -> torch.Tensor:
        return torch.stack([obs[f"{name}_{k}"] for k in range(1, n + 1)], -1)

    far = 10**6
    to_pick = torch.where(stack("pick_up") > 0, dist[loc][:, pick], far)
    fetchable = (stack("warehouse") > 0) & (stack("drop_off") < CAPACITY)
    to_bay = torch.where(fetchable, dist[loc][:, bays], far)
    has_asm = to_pick.min(-1).values < far
    has_job = has_asm | (to_bay.min(-1).values < far)
    target = torch.where(has_asm, pick[to_pick.argmin(-1)], bays[to_bay.argmin(-1)])
    carrying = status != EMPTY
    carried_target = torch.where(status <= n, drop[(status - 1).clamp(0, n - 1)], WAREHOUSE_DROP)
    target = torch.where(carrying, carried_target, target)
    action = torch.where(loc == target, torch.where(carrying, UNLOAD, LOAD), first[loc, target])
    return torch.where(carrying | has_job, action, IDLE)


# ---------------------------------------------------------------------- experiments (Figs. 4.6/4.7)
def assemblies(td: TensorDict) -> torch.Tensor:
    """Assemblies delivered to the warehouse by the step (the throughput of Figures 4.6/4.7)."""
    return td["assemblies_delivered"]


def _make_env(continuous: bool):
    def make(seeds, envs_per_learner: int, backend: str = "torch"):
        if backend != "torch":
            raise ValueError(f"unknown backend {backend!r}")
        return AGVEnv(seeds, envs_per_learner, continuous=continuous)

    return make


def _evaluator(unit: str):
    def make(config: TrainConfig) -> ThroughputEvaluator:
        return ThroughputEvaluator(
            horizon=1_000, burn_in=200, metric=assemblies, scale=1_000.0, unit=unit
        )

    return make


_EPSILON = linear_epsilon(1.0, 0.01, Fraction(1, 8))


def _tasks(continuous: bool) -> Tasks:
    """HAR, RAR, HDR (gamma 0.95, the text's better discount) and flat RVI Q-learning.

    In continuous time gains are per second and HDR discounts per second: ``0.95`` per mean
    action duration (10 s), the discrete-time discount per step. HH-learning is left out: its
    model over the hierarchy's 1.3 million states would not fit.
    """
    ct = continuous
    prior = GAIN_PRIOR_CT if ct else GAIN_PRIOR
    gamma = HDR_GAMMA ** (1 / CONTINUOUS.action_mean) if ct else HDR_GAMMA
    unit = f"{CONTINUOUS.action_mean:g} s" if ct else "step"
    steps = 1_000_000
    train = TrainConfig(steps=steps, eval_every=steps // 10, eval_episodes=4, log_every=steps // 50)
    flat = 8 * steps  # the flat learner gets more experience
    flat_train = replace(train, steps=flat, eval_every=flat // 10, log_every=flat // 50)
    return Tasks(
        graphs={"hierarchy": agv_hierarchy, "flat": flat_graph},
        offers=frozenset({"tabular", "single-agent", "continuing"}),
        exploration=_EPSILON,
        train=train,
        envs_per_learner=64,
        learner={"alpha": 0.1, "continuous": ct},
        per_algorithm={
            "har": {"learner": {"gain_prior": prior}},
            "rar": {"learner": {"gain_prior": prior}},
            "hdr": {
                "learner": {"gamma": gamma},
                "description": (
                    f"hierarchically optimal discounted RL (gamma {HDR_GAMMA} per {unit})"
                ),
            },
            "rvi-q": {
                "learner": {
                    "alpha": 0.3,
                    "reference_state": RVI_REFERENCE_STATE,
                    "time_unit": CONTINUOUS.action_mean if ct else 1.0,
                },
                "train": flat_train,
                "description": (
                    "flat RVI Q-learning over the 1,347,192 states (Abounadi et al. 2001)"
                ),
            },
        },
        without=frozenset({"hh"}),
    )


#: RVI Q-learning's reference state (``f(Q) = max_a Q(s_ref, a)``): AGV empty at WA, every
#: buffer empty, a part of each type waiting; among the most visited states (about 1.7% of the
#: steps under ``dispatch_action``)
RVI_REFERENCE_STATE = int(
    encode(
        torch.tensor(WAREHOUSE_DROP),
        torch.tensor(EMPTY),
        torch.zeros(N_STATIONS, dtype=torch.long),
        torch.zeros(N_STATIONS, dtype=torch.long),
        torch.ones(N_STATIONS, dtype=torch.long),
    )
)
#: optimistic start of the gains' running sums (g_0, t_0), see ``GainEstimate``: about twice
#: the arrival rate (one part per 12 steps / 100 s), worth 2,000 steps
GAIN_PRIOR = (0.2, 2_000.0)
GAIN_PRIOR_CT = (0.02, 20_000.0)
HDR_GAMMA = 0.95

DOMAIN = DomainSpec(
    name="agv",
    description="AGV scheduling (Figure 4.4), discrete time (Table 4.1)",
    make_env=_make_env(False),
    tasks=_tasks(False),
    make_evaluator=_evaluator("assemblies per 1,000 steps"),
)

DOMAIN_CT = DomainSpec(
    name="agv-ct",
    description="AGV scheduling (Figure 4.4), continuous time (Table 4.2)",
    make_env=_make_env(True),
    tasks=_tasks(True),
    make_evaluator=_evaluator("assemblies per 1,000 s"),
)
