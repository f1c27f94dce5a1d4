"""The point-door task's hybrid hierarchy (issue 33, held-out).

A Q(lambda) root over two waypoints, tile-coded Gaussian HPGRL subtasks below, every learner at
its defaults.

Root (2 abstract states: which room) -> ``ToDoor`` / ``ToGoal`` -> ``Heading`` (a continuous
primitive). Each waypoint subtask sees its position relative to its waypoint (2 features, tile
coded) and ends within ``GOAL_RADIUS`` of it; its only reward is the env's -1 per step.
"""

from __future__ import annotations

import torch

from envs.point_door import DOOR, GOAL, GOAL_RADIUS, SIZE, WALL_X
from hrl_torch.common.devices import constant_on
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners.hybrid import HybridLearner
from hrl_torch.learners.pg import HPGRLLearner, PGConfig
from hrl_torch.learners.q_lambda import QLambdaLearner
from hrl_torch.modules.tiles import TileCoder

WAYPOINTS = {"ToDoor": DOOR, "ToGoal": GOAL}


class ToWaypoint(Subtask):
    """Steer to a waypoint: features = position - waypoint; ends within ``GOAL_RADIUS``."""

    def __init__(self, name: str, waypoint: torch.Tensor, room: int | None = None) -> None:
        super().__init__(name, ["Heading"], n_features=2)
        self.waypoint, self.room = waypoint, room

    def features(self, obs):
        return obs["position"] - constant_on(self.waypoint, obs["position"].device)

    def terminated(self, obs):
        return self.features(obs).norm(dim=-1) <= GOAL_RADIUS

    def initiable(self, obs):  # I_i: only from its room (``room`` None: anywhere)
        position = obs["position"]  # (at the door counts as the right room)
        door = (position - constant_on(DOOR, position.device)).norm(dim=-1) <= GOAL_RADIUS
        right = (position[:, 0] > WALL_X) | door
        return right == bool(self.room) if self.room is not None else torch.ones_like(right)


def point_door_hierarchy(rooms: bool = False) -> TaskGraph:
    """Root (left / right room) -> ToDoor, ToGoal -> Heading.

    ``rooms``: ToDoor is initiable only in the left room and ToGoal only in the right one
    (otherwise both anywhere: ToGoal from the left room runs into the wall until the time
    limit, a cut the root never learns from).
    """
    root = Subtask(
        "Root",
        list(WAYPOINTS),
        n_states=2,
        abstract=lambda o: (o["position"][:, 0] > WALL_X).long(),
    )
    room = {"ToDoor": 0, "ToGoal": 1} if rooms else {}
    subtasks = [ToWaypoint(n, w, room.get(n)) for n, w in WAYPOINTS.items()]
    return TaskGraph("Root", [root, *subtasks, Primitive("Heading", action_dim=1)])


def relative_tile_coder(resolution: int = 10, n_tilings: int = 8) -> TileCoder:
    """Tiles over the position relative to a waypoint, ``[-10, 10]^2``."""
    return TileCoder([-SIZE, -SIZE], [SIZE, SIZE], [resolution, resolution], n_tilings)


def make_hybrid(
    graph: TaskGraph,
    n_learners: int,
    config: PGConfig | None = None,
    coder: TileCoder | None = None,
) -> HybridLearner:
    """Q(lambda) at the root and HPGRL at the waypoints, at their defaults unless given."""
    value = QLambdaLearner(graph, n_learners, nodes=["Root"])
    pg = HPGRLLearner(graph, n_learners, config, list(WAYPOINTS), coder or relative_tile_coder())
    return HybridLearner(graph, n_learners, value, pg)
