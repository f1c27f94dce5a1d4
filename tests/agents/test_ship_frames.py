import math

import pytest
import torch

from agents.ship import (
    DIAGONAL,
    LOCAL_GOAL,
    LOCAL_START,
    N_DIRECTIONS,
    STRAIGHT,
    SUBTASK_OF_DIRECTION,
    bearing,
    flat_tile_coder,
    grid_state,
    internal_reward,
    local_failure,
    local_success,
    low_level_tile_coder,
    orientation_shaping,
    to_global,
    to_local,
)
from envs.ship import ship_dynamics, wrap_degrees

DIRECTIONS = torch.arange(N_DIRECTIONS)


def _random_states(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 4, generator=g, dtype=torch.float64)
    return u * torch.tensor([1000.0, 1000.0, 360.0, 30.0]) - torch.tensor([0, 0, 180.0, 15.0])


def test_subtask_of_each_direction():
    assert SUBTASK_OF_DIRECTION.tolist() == [STRAIGHT, DIAGONAL] * 4


def test_reaching_the_local_goal_moves_the_ship_toward_its_direction():
    origin = torch.tensor([[500.0, 300.0]]).expand(8, 2)
    goal = LOCAL_GOAL[SUBTASK_OF_DIRECTION]
    local = torch.cat([goal, torch.zeros(8, 2)], dim=1)
    moved = to_global(local, origin, DIRECTIONS)[:, :2] - origin
    assert bearing(torch.zeros(8, 2), moved).tolist() == pytest.approx(
        [0, 45, 90, 135, 180, -135, -90, -45], abs=1e-4
    )
    length = [100 * math.sqrt(2) if k % 2 else 100.0 for k in range(8)]
    assert moved.norm(dim=-1).tolist() == pytest.approx(length, abs=1e-4)
    # e.g. north: the straight subtask's +x (east) in local coordinates is +y (north) globally
    assert moved[0].tolist() == pytest.approx([0.0, 100.0], abs=1e-4)
    assert moved[5].tolist() == pytest.approx([-100.0, -100.0], abs=1e-4)


def test_start_maps_to_local_start_and_heading_along_direction_maps_to_goal_bearing():
    state = torch.tensor([[321.0, 654.0, 0.0, 2.0]]).expand(8, 4).clone()
    state[:, 2] = wrap_degrees(45.0 * DIRECTIONS)  # heading exactly along direction k
    local = to_local(state, state[:, :2], DIRECTIONS)
    assert torch.allclose(local[:, :2], LOCAL_START[SUBTASK_OF_DIRECTION])
    goal_bearing = bearing(local[:, :2], LOCAL_GOAL[SUBTASK_OF_DIRECTION])
    assert torch.allclose(wrap_degrees(local[:, 2] - goal_bearing), torch.zeros(8), atol=1e-4)
    assert torch.equal(local[:, 3], state[:, 3])
    assert torch.allclose(orientation_shaping(local, SUBTASK_OF_DIRECTION), torch.zeros(8))


@pytest.mark.parametrize("k", range(8))
def test_round_trips(k):
    states = _random_states(50, seed=k)
    origin = _random_states(50, seed=10 + k)[:, :2]
    direction = torch.full((50,), k)
    local = to_local(states, origin, direction)
    back = to_global(local, origin, direction)
    assert torch.allclose(back[:, :2], states[:, :2], atol=1e-9)
    turned = wrap_degrees(back[:, 2] - states[:, 2])
    assert torch.allclose(turned, torch.zeros(50, dtype=torch.float64), atol=1e-9)
    assert torch.allclose(to_local(back, origin, direction), local, atol=1e-9)


@pytest.mark.parametrize("k", range(8))
def test_dynamics_commute_with_the_map(k):
    # Equation 5.4 in the local frame with the same turning rate = Equation 5.4 globally, mapped
    states = _random_states(40, seed=20 + k)
    origin = states[:, :2] + 7.0
    direction = torch.full((40,), k)
    rate = torch.linspace(-15, 15, 40, dtype=torch.float64)
    via_global = to_local(ship_dynamics(states, rate), origin, direction)
    via_local = ship_dynamics(to_local(states, origin, direction), rate)
    assert torch.allclose(via_global[:, [0, 1, 3]], via_local[:, [0, 1, 3]], atol=1e-9)
    assert torch.allclose(
        wrap_degrees(via_global[:, 2] - via_local[:, 2]),
        torch.zeros(40, dtype=torch.float64),
        atol=1e-9,
    )


def test_local_success_failure_and_rewards():
    subtask = torch.tensor([DIAGONAL, DIAGONAL, DIAGONAL, STRAIGHT, STRAIGHT, STRAIGHT])
    local = torch.tensor(
        [
            [133.0, 133.0, 45.0, 0.0],  # 9.9 m from (140, 140): success
            [132.0, 132.0, 45.0, 0.0],  # 11.3 m: not yet
            [151.0, 100.0, 45.0, 0.0],  # out of the local box
            [140.0, 85.0, 90.0, 0.0],  # exactly 10 m: success
            [75.0, -0.5, 90.0, 0.0],  # out
            [40.0, 75.0, 0.0, 0.0],  # heading north, the goal is east: G = exp(-1) ** 9 - 1
        ]
    )
    assert local_success(local, subtask).tolist() == [True, False, False, True, False, False]
    assert local_failure(local).tolist() == [False, False, True, False, True, False]
    g = orientation_shaping(local, subtask)
    assert g[5].item() == pytest.approx(math.exp(-(90.0**2) / 900.0) - 1.0)
    reward = internal_reward(local, subtask)
    assert reward[0].item() == pytest.approx(100.0 + g[0].item())
    assert reward[2].item() == pytest.approx(-100.0 + g[2].item())
    assert reward[5].item() == pytest.approx(g[5].item())


def test_shaping_wraps_angle_differences():
    local = torch.tensor([[40.0, 75.0, -179.0, 0.0], [40.0, 75.0, 179.0, 0.0]])
    subtask = torch.tensor([STRAIGHT, STRAIGHT])
    # goal bearing 90; heading -179 is 91 deg off (not 269), heading 179 is 89 deg off
    expected = [math.exp(-(91.0**2) / 900) - 1, math.exp(-(89.0**2) / 900) - 1]
    assert orientation_shaping(local, subtask).tolist() == pytest.approx(expected, rel=1e-5)


def test_grid_state():
    x = torch.tensor([0.0, 49.9, 50.0, 999.9, 1000.0, -0.4, 1000.6])
    y = torch.tensor([0.0, 0.0, 0.0, 999.9, 1000.0, 520.0, 20.0])
    assert grid_state(x, y).tolist() == [0, 0, 1, 399, 399, 200, 19]
    xs, ys = torch.meshgrid(
        torch.arange(20) * 50.0 + 25, torch.arange(20) * 50.0 + 25, indexing="ij"
    )
    assert sorted(grid_state(xs.flatten(), ys.flatten()).tolist()) == list(range(400))


def test_tile_coders_have_the_dissertation_sizes():
    assert low_level_tile_coder().n_features == 9 * 4_500 == 40_500
    assert flat_tile_coder().tiles_per_tiling == 72_000


def test_a_proportional_controller_solves_both_low_level_subtasks_from_any_heading():
    # the low-level subtasks are solvable from every start (scripts/ship_low_level_check.py)
    from scripts.ship_low_level_check import proportional, run

    for subtask in (0, 1):
        outcome, _, _ = run(subtask, proportional, 1000, seed=0)
        assert (outcome == 1).float().mean() >= 0.99
