"""A point behind a wall with a door: a held-out continuous task for the hybrid (issue 33).

## Description
A point moves in the square ``[0, 10]^2``. A wall at ``x = 5`` splits it into two rooms, open
only in the door ``4 <= y <= 6``. The point starts in the left room and must reach a goal disc
of radius ``GOAL_RADIUS`` around ``GOAL`` in the right room. None of the framework's defaults
were tuned on it.

## Action Space
``Box(-pi, pi, (1,))``: a heading in radians (0 = +x "east", pi/2 = +y "north"). Each step moves
the point ``STEP`` = 0.5 along it. A move whose segment crosses the wall outside the door, or
leaves the square, is not made (the point stays). An action outside the range or not finite
is a ``ValueError``.

## Observation
``position`` ``[2]`` = (x, y) in ``[0, 10]^2``.

## Rewards
-1 per step.

## Starting State
Uniform in ``[0.5, 4.5] x [0.5, 9.5]`` (the left room, away from its walls).

## Episode End
Terminated when the point is within ``GOAL_RADIUS`` of ``GOAL``; truncated after
``max_episode_steps`` (default 200: ten times the longest shortest path).

## Reference (fixed before any learner ran on it)
``door_rule``: head straight for the door's centre ``DOOR`` until within ``STEP`` of it, then
straight for the goal. It reaches the goal from every start; its mean steps on the evaluation
starts (``scripts/point_door_reference.py``) is the reference.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from hrl_torch.common.devices import constant_on
from hrl_torch.env.batched import BatchedEnv

SIZE, WALL_X, DOOR_Y = 10.0, 5.0, (4.0, 6.0)
STEP = 0.5
GOAL = torch.tensor([8.5, 5.0])
DOOR = torch.tensor([5.0, 5.0])
GOAL_RADIUS = 0.5
START_LOW, START_HIGH = torch.tensor([0.5, 0.5]), torch.tensor([4.5, 9.5])
MAX_EPISODE_STEPS = 200


def blocked(start: torch.Tensor, end: torch.Tensor) -> torch.Tensor:
    """``[B]``: the move ``start -> end`` (``[B, 2]``) is not made.

    It crosses the wall outside the door, or it leaves the square.
    """
    (x0, y0), (x1, y1) = start.unbind(-1), end.unbind(-1)
    crosses = (x0 < WALL_X) != (x1 < WALL_X)
    dx = torch.where(x1 == x0, torch.ones_like(x0), x1 - x0)
    y_at = y0 + (WALL_X - x0) / dx * (y1 - y0)
    through_door = (y_at >= DOOR_Y[0]) & (y_at <= DOOR_Y[1])
    outside = ((end < 0) | (end > SIZE)).any(-1)
    return (crosses & ~through_door) | outside


def move(position: torch.Tensor, heading: torch.Tensor) -> torch.Tensor:
    """One step of ``STEP`` along ``heading [B]`` from ``position [B, 2]`` (a blocked one stays)."""
    end = position + STEP * torch.stack([torch.cos(heading), torch.sin(heading)], -1)
    return torch.where(blocked(position, end)[:, None], position, end)


def heading_to(position: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The heading ``[B]`` from ``position [B, 2]`` straight to ``target`` (``[2]``)."""
    d = target - position
    return torch.atan2(d[:, 1], d[:, 0])


def door_rule(position: torch.Tensor, aiming_at_goal: torch.Tensor):
    """The reference controller: ``(heading [B], aiming_at_goal [B])`` for the next step.

    A row aims at the door until it is within ``STEP`` of the door's centre (or in the right
    room), then at the goal for the rest of its episode.
    """
    door, goal = constant_on(DOOR, position.device), constant_on(GOAL, position.device)
    near = ((position - door).norm(dim=-1) <= STEP) | (position[:, 0] > WALL_X)
    aiming_at_goal = aiming_at_goal | near
    heading = torch.where(aiming_at_goal, heading_to(position, goal), heading_to(position, door))
    return heading, aiming_at_goal


class PointDoorEnv(BatchedEnv):
    """Torch-batched point behind a wall with a door (see the module docstring).

    Args:
        seeds: one seed per learner.
        envs_per_learner: ``E``.
        max_episode_steps: time limit (``None``: none).
        device: where the state lives.
    """

    state_keys = ("position",)
    observation_bounds = {"position": ([0.0, 0.0], [SIZE, SIZE])}
    action_bounds = ([-math.pi], [math.pi])

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        max_episode_steps: int | None = MAX_EPISODE_STEPS,
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__(seeds, envs_per_learner, None, max_episode_steps, device)
        self.position = torch.zeros(self.batch_size, 2, device=self.device)

    def _reset_rows(self, mask: torch.Tensor) -> None:
        u = self.rng.uniform(2)  # every row draws (the streams never depend on data)
        low, high = constant_on(START_LOW, self.device), constant_on(START_HIGH, self.device)
        self.position = torch.where(mask[:, None], low + (high - low) * u, self.position)

    def _step_all(self, action: torch.Tensor):
        heading = action.reshape(-1).float()
        if action.shape not in ((self.batch_size,), (self.batch_size, 1)):
            raise ValueError(f"action must have shape [{self.batch_size}, 1], got {action.shape}")
        ok = heading.abs() <= math.pi  # NaN compares False
        if not bool((ok | self.done).all()):
            row = int((~ok & ~self.done).nonzero()[0])
            raise ValueError(f"heading {float(heading[row])} outside [-pi, pi] (env row {row})")
        self.position = move(self.position, torch.where(ok, heading, 0.0))
        goal = constant_on(GOAL, self.device)
        at_goal = (self.position - goal).norm(dim=-1) <= GOAL_RADIUS
        reward = torch.full((self.batch_size,), -1.0, device=self.device)
        return reward, torch.ones_like(reward), at_goal

    def _observe(self) -> dict[str, torch.Tensor]:
        return {"position": self.position.clone()}
