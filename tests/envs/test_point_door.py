"""The held-out point-door task (issue 33): its walls, its contract and its fixed reference."""

import math

import pytest
import torch

from agents.point_door import point_door_hierarchy
from envs.point_door import PointDoorEnv, move
from hrl_torch.env.envcheck import check_env
from scripts.point_door_reference import rule_episodes, shortest_steps


def test_the_wall_blocks_outside_the_door_and_the_door_lets_through():
    start = torch.tensor([[4.8, 8.0], [4.8, 5.0], [0.2, 5.0]])
    heading = torch.tensor([0.0, 0.0, math.pi])  # east, east, west (out of the square)
    end = move(start, heading)
    assert torch.equal(end[0], start[0])  # the wall at y = 8
    assert torch.allclose(end[1], torch.tensor([5.3, 5.0]))  # through the door
    assert torch.equal(end[2], start[2])  # stays in the square


def test_the_env_keeps_the_batched_contract():
    check_env(PointDoorEnv([0, 1], 3), point_door_hierarchy(), lambda s, e: PointDoorEnv(s, e))
    with pytest.raises(ValueError, match="outside"):
        PointDoorEnv([0], 2).step(torch.tensor([[4.0], [0.0]]))


def test_the_reference_is_the_one_fixed_first():
    steps, success, start = rule_episodes()
    assert bool(success.all())
    assert abs(steps.double().mean().item() - 13.76) < 1e-6  # docs/defaults.md
    assert bool((shortest_steps(start) <= steps).all())  # (a lower bound)
