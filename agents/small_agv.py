"""Task graph of the small AGV task (Figure 4.2), reconstructed from Section 4.3.1.

The figure is not in the text; this graph is built so that the policies the text describes
come out of it exactly (``hrl_torch.analysis`` computes them)::

    Root ─┬─ GetPart1 ─┬─ NavM1 ── South, North, East, West        (inside the machine room)
          │            └─ Load
          ├─ GetPart2 ─┬─ NavM2 ── South, North, East, West
          │            └─ Load
          ├─ DeliverPart1 ─┬─ NavG1 ── South, North, East, West
          │                ├─ Unload
          │                └─ South, North, East, West              (the way back)
          └─ DeliverPart2 ─┬─ NavG2 ── ...
                           ├─ Unload
                           └─ South, North, East, West

- ``GetPartI`` (empty AGV in the machine room): drive to machine ``Mi`` and load; ends when the
  AGV carries a part. Its navigation never leaves the machine room.
- ``DeliverPartI`` (AGV carrying part ``i``): drive to ``Gi``, unload, and bring the AGV back
  into the machine room; it ends when the AGV is empty in the machine room, through either
  door. The way back is the subtask's own choice of moves.
- ``Root`` (continuing) picks the machine to serve whenever the AGV is empty.

Why the optimal policies differ (numbers from the map of ``envs.agv_small``): the terminal set
of ``DeliverPart1`` contains both doors' machine-room sides. Its own (recursive) criterion,
the reward until it terminates, leaves G1 through the nearest door D2 (2 moves, against 4
through D1); from there M1 is 11 moves away but M2 only 1, so the root, optimising its gain
given that child, serves M2, whose delivery returns through D1 next to M1: the alternation
M1 -> G1 (D1) -> D2 -> M2 -> G2 (D2) -> D1 -> M1 of the text (gain 3/20 = 0.15). A
hierarchically optimal ``DeliverPart1`` sees the reward after it ends (the Task-Stack is part of
its state) and goes back through D1, next to M1: always serving M1 earns 9 per 12 steps (0.75),
which is also the flat optimum. The alternative "always M1" under the recursive children
earns only 1 per 20 steps (0.05). Every local criterion the text uses for subtasks picks the
nearest door: MAXQ's total (discounted) reward, HH-learning's reward minus the global gain,
and RAR's per-subtask gain ``(21 - n) / n`` over an ``n``-step delivery.

State abstractions:

==================  ===============================================  ======
node                relevant variables                               states
==================  ===============================================  ======
Root                AGV location, status                             78
GetPartI            AGV location                                     26
DeliverPartI        AGV location, whether it carries a part          52
NavMI, NavGI        AGV location                                     26
moves, Load         none (always -1)                                 1
Unload              AGV location, status (+20, +1 or -1)             78
==================  ===============================================  ======
"""

from __future__ import annotations

from fractions import Fraction

import torch
from tensordict import TensorDict

from envs.agv_small import (
    DELIVERY_WEIGHT,
    EMPTY,
    GOALS,
    MACHINE_ROOM,
    MACHINES,
    MOVE_TARGET,
    N_ACTIONS,
    N_LOCATIONS,
    N_STATES,
    ROOM_OF,
    SmallAGVEnv,
    decode,
)
from hrl_torch.common.config import Make
from hrl_torch.common.devices import constant_on
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import (
    MaxQLearner,
)
from hrl_torch.modules.exploration import linear_epsilon
from hrl_torch.runs.algorithms import Tasks
from hrl_torch.runs.domain import AlgoSpec, DomainSpec
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.continuing import ThroughputEvaluator

MOVES = ("South", "North", "East", "West")  # env actions 0-3


class Navigate(Subtask):
    """Drive to one location; abstraction: AGV location.

    Args:
        name: node name.
        target: location index to reach.
        room: if given, the subtask starts and moves only inside this room.
    """

    def __init__(self, name: str, target: int, room: int | None = None) -> None:
        super().__init__(name, MOVES, n_states=N_LOCATIONS)
        self.room = room
        self.register_buffer("target", torch.tensor(target), persistent=False)
        self.register_buffer("move_target", MOVE_TARGET.clone(), persistent=False)
        self.register_buffer("room_of", ROOM_OF.clone(), persistent=False)

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        return obs["location"]

    def terminated(self, obs: TensorDict) -> torch.Tensor:
        return obs["location"] == self.target

    def initiable(self, obs: TensorDict) -> torch.Tensor:
        if self.room is None:
            return torch.ones_like(obs["location"], dtype=torch.bool)
        return obs["room"] == self.room

    def child_mask(self, obs: TensorDict) -> torch.Tensor | None:
        if self.room is None:
            return None
        return self.room_of[self.move_target[obs["location"]]] == self.room


def _get_part(part: int) -> Subtask:
    """GetPartI: in the machine room with an empty AGV, go to machine ``Mi`` and load."""
    machine = MACHINES[part - 1]
    return Subtask(
        f"GetPart{part}",
        [f"NavM{part}", "Load"],
        n_states=N_LOCATIONS,
        abstract=lambda o: o["location"],
        initiable=lambda o: (o["status"] == EMPTY) & (o["room"] == MACHINE_ROOM),
        terminated=lambda o: o["status"] != EMPTY,
        child_mask=lambda o: torch.stack(
            [torch.ones_like(o["location"], dtype=torch.bool), o["location"] == machine], 1
        ),
    )


def _deliver_part(part: int) -> Subtask:
    """DeliverPartI: carry part ``i`` to ``Gi``, unload, return to the machine room."""
    goal = GOALS[part - 1]

    def mask(o: TensorDict) -> torch.Tensor:
        carrying = o["status"] != EMPTY
        at_goal = o["location"] == goal
        return torch.stack([carrying, carrying & at_goal, *[~carrying] * len(MOVES)], 1)

    return Subtask(
        f"DeliverPart{part}",
        [f"NavG{part}", "Unload", *MOVES],
        n_states=2 * N_LOCATIONS,
        abstract=lambda o: o["location"] * 2 + (o["status"] != EMPTY).long(),
        initiable=lambda o: o["status"] == part,
        terminated=lambda o: (o["status"] == EMPTY) & (o["room"] == MACHINE_ROOM),
        child_mask=mask,
    )


def small_agv_hierarchy() -> TaskGraph:
    """The reconstructed Figure 4.2 task graph with the state abstractions above."""
    root = Subtask(
        "Root",
        ["GetPart1", "GetPart2", "DeliverPart1", "DeliverPart2"],
        n_states=N_STATES,
        abstract=lambda o: o["observation"],
    )
    navs = [
        Navigate("NavM1", MACHINES[0], MACHINE_ROOM),
        Navigate("NavM2", MACHINES[1], MACHINE_ROOM),
        Navigate("NavG1", GOALS[0]),
        Navigate("NavG2", GOALS[1]),
    ]
    prims = [Primitive(name, k) for k, name in enumerate(MOVES)]
    prims += [Primitive("Load", 4), Primitive("Unload", 5, N_STATES, lambda o: o["observation"])]
    parts = [_get_part(1), _get_part(2), _deliver_part(1), _deliver_part(2)]
    return tabulated(TaskGraph("Root", [root, *parts, *navs, *prims], n_actions=N_ACTIONS))


def tabulated(graph: TaskGraph) -> TaskGraph:
    """``graph`` with its context computed once for the 78 states (a lookup per step).

    Every predicate here reads the state's fields alone (not the step's ``delivered``).
    """
    graph.tabulate(TensorDict(decode(torch.arange(N_STATES)), batch_size=[N_STATES]))
    return graph


def flat_graph() -> TaskGraph:
    """One root over the six primitive actions, abstraction = the 78 states (flat learners)."""
    names = [*MOVES, "Load", "Unload"]
    root = Subtask("Root", names, n_states=N_STATES, abstract=lambda o: o["observation"])
    graph = TaskGraph(
        "Root", [root, *(Primitive(n, k) for k, n in enumerate(names))], n_actions=N_ACTIONS
    )
    return tabulated(graph)


# ---------------------------------------------------------------------- experiments (Fig. 4.3)
def weighted_deliveries(td: TensorDict) -> torch.Tensor:
    """``20 * part 1 + 1 * part 2`` delivered by the step: Figure 4.3's throughput measure."""
    return constant_on(DELIVERY_WEIGHT, td.device)[td["delivered"]]


def make_env(seeds, envs_per_learner: int, backend: str = "torch") -> SmallAGVEnv:
    """The batched small AGV for ``seeds`` (torch backend only)."""
    if backend != "torch":
        raise ValueError(f"unknown backend {backend!r}")
    return SmallAGVEnv(seeds, envs_per_learner)


def _evaluator(config: TrainConfig) -> ThroughputEvaluator:
    # the task is deterministic and every optimal cycle divides 240 steps (12 and 20)
    return ThroughputEvaluator(
        horizon=240,
        burn_in=60,
        metric=weighted_deliveries,
        scale=10_000.0,
        unit="20 x part 1 + part 2 per 10,000 steps",
    )


# decays early to a small floor: with average-reward learners the floor sets how far the
# gain (measured on the exploring behaviour) lags the greedy policy's gain
_EPSILON = linear_epsilon(1.0, 0.01, Fraction(1, 8))


#: Figure 4.3's discount for the discounted learners (the text found 0.99 best)
GAMMA = 0.99
#: optimistic starts of the gains' running sums (g_0, t_0) (see ``GainEstimate``): HAR needs a
#: short one, RAR and HH a longer one (docs/reproduction.md, Figure 4.3)
HAR_GAIN_PRIOR = (1.0, 2_000.0)
RAR_GAIN_PRIOR = (1.0, 20_000.0)
HH_GAIN_PRIOR = (1.0, 20_000.0)
_TRAIN = TrainConfig(steps=150_000, eval_every=5_000, eval_episodes=4, log_every=5_000)


DOMAIN = DomainSpec(
    name="small-agv",
    description="small AGV scheduling task (Figure 4.2), continuing",
    make_env=make_env,
    make_evaluator=_evaluator,
    reference={
        "hierarchically optimal 16,667": 10_000 * 20 / 12,
        "recursively optimal 10,500": 10_500.0,
    },
    tasks=Tasks(
        graphs={"hierarchy": small_agv_hierarchy, "flat": flat_graph},
        offers=frozenset({"tabular", "single-agent", "continuing"}),
        exploration=_EPSILON,
        train=_TRAIN,
        envs_per_learner=16,
        per_algorithm={  # (HH-learning has no step size: alpha is set per algorithm)
            "har": {"learner": {"alpha": 0.2, "gain_prior": HAR_GAIN_PRIOR}},
            "rar": {"learner": {"alpha": 0.2, "gain_prior": RAR_GAIN_PRIOR}},
            "hdr": {
                "learner": {"alpha": 0.2, "gamma": GAMMA},
                "description": f"hierarchically optimal discounted RL (MAXQ-Q + CE, gamma {GAMMA})",
            },
            "hh": {"learner": {"gain_prior": HH_GAIN_PRIOR}},
            "rvi-q": {
                "learner": {"alpha": 0.2},
                "description": "flat RVI Q-learning over the 78 states (not in Figure 4.3)",
            },
        },
    ),
    algos={  # (discounted MAXQ-Q on a continuing task: not the episodic family)
        "maxq-q": AlgoSpec(
            make_graph=small_agv_hierarchy,
            learner=Make(MaxQLearner, alpha=0.2, gamma=GAMMA),
            exploration=_EPSILON,
            train=_TRAIN,
            envs_per_learner=16,
            description=f"MAXQ-Q (Dietterich 2000), gamma {GAMMA}",
        ),
    },
)
