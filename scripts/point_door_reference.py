"""The point-door task's reference (issue 33, held-out): the door rule on the evaluation starts.

Fixed before any learner ran on the task. The evaluation plays one greedy episode from each row
of ``PointDoorEnv([EVAL_SEED], EVAL_EPISODES)`` after a reset (the trainer's evaluation restarts
the eval env's streams, so every evaluation meets these starts). Prints the rule's success rate,
mean steps and return, and the shortest-path bound (straight to the goal disc, or via the
nearer door post when the straight line meets the wall).

    .venv/bin/python scripts/point_door_reference.py
"""

from __future__ import annotations

import math

import torch

from envs.point_door import DOOR_Y, GOAL, GOAL_RADIUS, STEP, WALL_X, PointDoorEnv, door_rule

EVAL_SEED, EVAL_EPISODES = 123, 100


def rule_episodes(seed: int = EVAL_SEED, n: int = EVAL_EPISODES, limit: int = 200):
    """``(steps [n], success [n], starts [n, 2])`` of the door rule from the eval starts."""
    env = PointDoorEnv([seed], n, max_episode_steps=limit)
    start = env.reset()["position"].clone()
    aiming = torch.zeros(n, dtype=torch.bool)
    steps = torch.zeros(n, dtype=torch.long)
    done = torch.zeros(n, dtype=torch.bool)
    success = torch.zeros(n, dtype=torch.bool)
    obs = {"position": start}
    for _ in range(limit):
        heading, aiming = door_rule(obs["position"], aiming)
        obs = env.step(heading[:, None])
        live = ~done
        steps += live
        success |= live & obs["terminated"]
        done |= obs["terminated"] | obs["truncated"]
        if bool(done.all()):
            break
    return steps, success, start


def shortest_steps(start: torch.Tensor) -> torch.Tensor:
    """A lower bound on the steps from each start ``[n, 2]``.

    The shortest path's length to the goal disc over ``STEP``, rounded up.
    """
    goal = GOAL
    d = goal - start
    y_at = start[:, 1] + (WALL_X - start[:, 0]) / d[:, 0] * d[:, 1]
    straight = (y_at >= DOOR_Y[0]) & (y_at <= DOOR_Y[1])
    posts = torch.tensor([[WALL_X, DOOR_Y[0]], [WALL_X, DOOR_Y[1]]])
    via = ((start[:, None] - posts).norm(dim=-1) + (goal - posts).norm(dim=-1)).min(1).values
    length = torch.where(straight, d.norm(dim=-1), via) - GOAL_RADIUS
    return torch.ceil(length / STEP - 1e-6)


def main() -> None:
    steps, success, start = rule_episodes()
    bound = shortest_steps(start)
    mean = steps.double().mean().item()
    print(
        f"door rule: success {success.double().mean().item():.3f}, mean steps {mean:.2f}, "
        f"return {-mean:.2f}, longest {int(steps.max())}"
    )
    print(
        f"shortest-path bound: mean steps {bound.mean().item():.2f} "
        f"(rule / bound {mean / bound.mean().item():.3f})"
    )
    assert math.isfinite(mean)


if __name__ == "__main__":
    main()
