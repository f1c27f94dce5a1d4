"""Held-out domains (issue 33, Build 6): tasks none of the registered defaults were tuned on.

Built from the docs as a new user would (``docs/multiagent-walkthrough.md``,
``docs/your-own-hierarchy.md``), with the settings of the comparable registered domains left
as they are, and not registered with the built-in domains: load them as a plugin module,

    hrl-torch --domain-module agents.heldout train heldout-couriers --algo cooperative

- ``heldout-couriers`` (``envs/heldout/couriers.py``): two couriers, three parcels in a
  corridor, the team pays -1 per step. Each courier runs Root -> Fetch0..2 -> Left, Right,
  Pick; the root sees its own cell, the other courier's cell (the walkthrough's advice for
  splitting by position) and the parcels left. ``cooperative`` and ``selfish`` take the
  walkthrough plugin's settings (``examples/hrl-two-robots``: MAXQ-Q, alpha 0.3, gamma 1,
  init -10, epsilon 1 -> 0.05 over half the budget, 16 envs per learner). Init -10 is
  pessimistic here as docs/defaults.md asks (the longest optimal episode takes 9 steps).
- ``heldout-polling`` (``envs/heldout/polling.py``): one server, two queues, continuous time.
  Root -> Serve0, Serve1, Wait; Serve_k -> Switch, Process (switch to queue k if the server
  is elsewhere, then serve one job). Every registered continuing algorithm (``har``, ``rar``,
  ``hdr``, ``hh``, ``rvi-q``) with its registered settings; the domain sets only
  ``continuous=True`` (an event-driven task), the AGV domains' exploration (epsilon
  1 -> 0.01 over the first eighth) and the budget.

The references (exact optimum, rules) are in ``scripts/heldout_references.py`` and
``docs/heldout.md``.
"""

from __future__ import annotations

from fractions import Fraction

import torch

from envs.heldout import couriers, polling
from hrl_torch.common.config import Make
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import linear_epsilon
from hrl_torch.multiagent.cooperative import Cooperation, MultiAgentConfig, cooperative_graph
from hrl_torch.runs.algorithms import Tasks
from hrl_torch.runs.domain import DomainSpec, algo_family
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.continuing import ThroughputEvaluator

# ---------------------------------------------------------------------- couriers
L, MASKS = couriers.LENGTH, couriers.N_MASKS


def _fetch(k: int) -> Subtask:
    """Go to parcel ``k`` and pick it; ends when it is gone (picked by either courier)."""
    return Subtask(
        f"Fetch{k}",
        ["Left", "Right", "Pick"],
        n_states=L,
        abstract=lambda o: o["pos"],
        initiable=lambda o: (o["parcels"] >> k) & 1 == 1,
        terminated=lambda o: (o["parcels"] >> k) & 1 == 0,
    )


def courier_hierarchy() -> TaskGraph:
    """One courier's graph: Root (own cell, other's cell, parcels: 648 states) -> Fetch0..2."""
    root = Subtask(
        "Root",
        [f"Fetch{k}" for k in range(len(couriers.PARCELS))],
        n_states=L * L * MASKS,
        abstract=lambda o: (o["pos"] * L + o["other"]) * MASKS + o["parcels"],
    )
    moves = [
        Primitive("Left", couriers.LEFT),
        Primitive("Right", couriers.RIGHT),
        Primitive("Pick", couriers.PICK),
    ]
    fetch = [_fetch(k) for k in range(len(couriers.PARCELS))]
    return TaskGraph("Root", [root, *fetch, *moves], n_actions=3)


COOPERATION = Cooperation((("Root",),))
#: the budget, fixed before any learner ran: 5x the walkthrough's 12,000 steps (the root has
#: 648 states against the walkthrough's 28)
COURIER_STEPS = 60_000


def make_couriers(seeds, envs_per_learner, backend="torch"):
    """The couriers env (torch backend only)."""
    if backend != "torch":
        raise ValueError(f"unknown backend {backend!r}")
    return couriers.CouriersEnv(seeds, envs_per_learner)


_courier_spec = algo_family(
    learner=Make(MaxQLearner, alpha=0.3, gamma=1.0, init=-10.0),
    exploration=linear_epsilon(1.0, 0.05, 0.5),
    train=TrainConfig(steps=COURIER_STEPS, eval_every=COURIER_STEPS // 6, eval_episodes=200),
    envs_per_learner=16,
)
COURIERS = DomainSpec(
    name="heldout-couriers",
    make_env=make_couriers,
    description="held-out: two couriers, three parcels in a corridor (cooperative, episodic)",
    algos={
        "cooperative": _courier_spec(
            lambda: cooperative_graph(courier_hierarchy(), COOPERATION, 2),
            "Cooperative HRL: the root's completions also see the other courier's task",
            MultiAgentConfig(COOPERATION),
        ),
        "selfish": _courier_spec(courier_hierarchy, "selfish HRL: each courier learns alone"),
    },
)


# ---------------------------------------------------------------------- polling
def _serve(k: int) -> Subtask:
    """Serve one job of queue ``k``: switch there if the server is elsewhere, then serve."""

    def child_mask(o):
        there = o["where"] == k
        return torch.stack([~there, there], -1)

    return Subtask(
        f"Serve{k}",
        ["Switch", "Process"],
        n_states=2,
        abstract=lambda o: o["where"],
        initiable=lambda o: o[f"q{k}"] > 0,
        terminated=lambda o: o["served"] == k + 1,
        child_mask=child_mask,
        event_termination=True,
    )


def _primitives() -> list[Primitive]:
    # Process pays the queue's price: it must see where the server is (leaf irrelevance)
    return [
        Primitive("Process", polling.SERVE, 2, lambda o: o["where"]),
        Primitive("Switch", polling.SWITCH),
        Primitive("Wait", polling.WAIT),
    ]


def _polling_root(children: list[str]) -> Subtask:
    """The root over ``children`` that sees where the server is and both queues (50 states)."""
    return Subtask("Root", children, n_states=polling.N_STATES, abstract=lambda o: o["state"])


def polling_hierarchy() -> TaskGraph:
    """Root (where, both queues: 50 states) -> Serve0, Serve1, Wait."""
    root = _polling_root(["Serve0", "Serve1", "Wait"])
    return TaskGraph("Root", [root, _serve(0), _serve(1), *_primitives()], n_actions=3)


def polling_flat() -> TaskGraph:
    """One root over Process, Switch, Wait and the 50 states (flat learners)."""
    root = _polling_root(["Process", "Switch", "Wait"])
    return TaskGraph("Root", [root, *_primitives()], n_actions=3)


#: the budget, fixed before any learner ran (steps per env row; about 1.2 time units a step)
POLLING_STEPS = 100_000


def make_polling(seeds, envs_per_learner, backend="torch"):
    """The polling env (torch backend only)."""
    if backend != "torch":
        raise ValueError(f"unknown backend {backend!r}")
    return polling.PollingEnv(seeds, envs_per_learner)


def _polling_evaluator(config: TrainConfig) -> ThroughputEvaluator:
    return ThroughputEvaluator(
        horizon_time=2_000.0, burn_in_time=50.0, max_steps=5_000, unit="reward per unit of time"
    )


POLLING = DomainSpec(
    name="heldout-polling",
    make_env=make_polling,
    description="held-out: one server, two queues, continuous time (continuing SMDP)",
    make_evaluator=_polling_evaluator,
    tasks=Tasks(
        graphs={"hierarchy": polling_hierarchy, "flat": polling_flat},
        offers=frozenset({"tabular", "single-agent", "continuing"}),
        exploration=linear_epsilon(1.0, 0.01, Fraction(1, 8)),
        train=TrainConfig(
            steps=POLLING_STEPS, eval_every=POLLING_STEPS // 5, eval_episodes=16, log_every=5_000
        ),
        envs_per_learner=16,
        learner={"continuous": True},
    ),
)

DOMAINS = [COURIERS, POLLING]
