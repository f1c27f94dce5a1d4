import math

import gymnasium
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from torchrl.envs.utils import check_env_specs

import envs  # noqa: F401  (registers hrl/ShipSteering-v0)
from envs.ship import (
    FIGURE_5_12_STARTS,
    ShipParams,
    ShipSteeringEnv,
    gate_crossed,
    ship_dynamics,
    wrap_degrees,
)
from hrl_torch.env.torchrl_env import TorchRLEnv


def test_one_step_equals_equation_5_4_by_hand():
    x, y, th, thd, r = 700.0, 700.0, 100.0, 3.65, -12.0
    nxt = ship_dynamics(
        torch.tensor([[x, y, th, thd]], dtype=torch.float64), torch.tensor([r], dtype=torch.float64)
    )
    d, v, t = 0.2, 3.0, 5.0
    expected = [
        x + d * v * math.sin(math.radians(th)),
        y + d * v * math.cos(math.radians(th)),
        th + d * thd,
        thd + d * (r - thd) / t,
    ]
    assert nxt[0].tolist() == pytest.approx(expected, abs=1e-9)
    assert expected[0] == pytest.approx(700.5909, abs=1e-4)  # sin(100 deg) = 0.98481


def test_heading_wraps_and_turn_rate_stays_in_range():
    nxt = ship_dynamics(torch.tensor([[500.0, 500.0, 179.0, 15.0]]), torch.tensor([15.0]))
    assert nxt[0, 2].item() == pytest.approx(-178.0)
    assert nxt[0, 3].item() == 15.0
    w = wrap_degrees(torch.tensor([180.0, -180.0, 540.0, -1e-9, 359.999]))
    assert torch.all((w >= -180) & (w < 180))
    assert w[:3].tolist() == [-180.0, -180.0, -180.0]


def _wrap_by_comparison(angle):
    shifted = torch.remainder(angle + 180.0, 360.0)
    shifted = torch.where(shifted >= 360.0, shifted - 360.0, shifted)  # float rounding
    return shifted - 180.0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_wrap_degrees_equals_the_comparison_form_bit_for_bit(dtype):
    # near the edges, where remainder(a + 180, 360) rounds to 360, and far away
    edges = torch.tensor([-540.0, -180.0, 0.0, 180.0, 540.0], dtype=dtype)
    near = [edges, edges]  # stepping down and up, one float at a time
    for _ in range(40):
        near += [torch.nextafter(near[-2], edges - 1), torch.nextafter(near[-1], edges + 1)]
    g = torch.Generator().manual_seed(0)
    spread = (torch.rand(100_000, generator=g, dtype=dtype) - 0.5) * 1e4
    tiny = -torch.logspace(-45, 2, 2_000, dtype=torch.float64).to(dtype)
    x = torch.cat([*near, spread, tiny, tiny - 180.0, torch.tensor([float("nan")], dtype=dtype)])
    got, want = wrap_degrees(x), _wrap_by_comparison(x)
    bits = torch.int32 if dtype == torch.float32 else torch.int64
    assert torch.equal(got.isnan(), want.isnan())
    ok = got.isnan()
    assert torch.equal(got[~ok].view(bits), want[~ok].view(bits))
    assert bool(((got[~ok] >= -180) & (got[~ok] < 180)).all())


@pytest.mark.parametrize(
    ("start", "end", "crossed"),
    [
        ((400.0, 399.5), (400.0, 400.5), True),  # straight up through the middle
        ((400.0, 400.5), (400.0, 399.5), True),  # downward counts too
        ((350.0, 399.0), (350.0, 401.0), True),  # left end included
        ((450.0, 399.0), (450.0, 401.0), True),  # right end included
        ((349.9, 399.0), (349.9, 401.0), False),  # just outside
        ((450.1, 399.0), (450.1, 401.0), False),
        ((340.0, 399.0), (360.0, 401.0), True),  # diagonal: meets the line at x = 350
        ((330.0, 399.0), (350.0, 401.0), False),  # meets the line at x = 340
        ((400.0, 399.0), (400.0, 400.0), True),  # ends exactly on the line from below
        ((400.0, 400.0), (400.0, 401.0), False),  # ... and is not counted again
        ((400.0, 401.0), (400.0, 400.0), False),  # touches from above: not crossed
        ((400.0, 400.0), (400.0, 399.0), True),  # ... until it goes below
        ((380.0, 400.0), (420.0, 400.0), False),  # sailing along the line
        ((400.0, 390.0), (400.0, 399.9), False),  # below the whole time
    ],
)
def test_gate_crossing(start, end, crossed):
    got = gate_crossed(torch.tensor([start]), torch.tensor([end]))
    assert bool(got[0]) is crossed


def test_episode_succeeds_through_the_gate():
    env = ShipSteeringEnv(seeds=[0], envs_per_learner=2, action_repeat=3)
    env.reset_to(torch.tensor([[400.0, 399.0, 0.0, 0.0], [400.0, 395.0, 0.0, 0.0]]))
    td = env.step(torch.zeros(2, 1))
    # row 0 crosses in its 2nd interval (399 -> 399.6 -> 400.2) and stops there
    assert td["terminated"].tolist() == [True, False]
    assert td["success"].tolist() == [True, False]
    assert td["reward"].tolist() == [-1.0, -1.0]
    assert td["duration"][0].item() == pytest.approx(0.4)
    assert td["duration"][1].item() == pytest.approx(0.6)
    assert td["y"][0].item() == pytest.approx(400.2, abs=1e-4)
    td = env.step(torch.zeros(2, 1))  # row 0 auto-resets, row 1 keeps sailing
    assert td["is_init"].tolist() == [True, False]
    assert td["success"].tolist() == [False, False]


def test_leaving_the_box_is_a_failure():
    env = ShipSteeringEnv(seeds=[0], envs_per_learner=3, action_repeat=1)
    env.reset_to(
        torch.tensor(
            [[0.3, 500.0, -90.0, 0.0], [999.9, 500.0, 90.0, 0.0], [500.0, 999.5, 0.0, 0.0]]
        )
    )
    td = env.step(torch.zeros(3, 1))
    assert td["terminated"].tolist() == [True, True, True]
    assert td["success"].tolist() == [False, False, False]
    assert td["x"][0] < 0 and td["x"][1] > 1000 and td["y"][2] > 1000
    assert torch.all(td["observation"][:, :2] >= -1) and torch.all(td["observation"][:, :2] <= 1001)


@pytest.mark.parametrize("bad", [15.01, -16.0, float("nan"), float("inf")])
def test_invalid_action_raises(bad):
    env = ShipSteeringEnv(seeds=[0], envs_per_learner=2)
    env.reset()
    with pytest.raises(ValueError, match="turning rate"):
        env.step(torch.tensor([[0.0], [bad]]))


def test_a_row_being_reset_may_send_any_action():
    env = ShipSteeringEnv(seeds=[0], envs_per_learner=2, action_repeat=1)
    env.reset_to(torch.tensor([[0.3, 500.0, -90.0, 0.0], [500.0, 500.0, 0.0, 0.0]]))
    assert env.step(torch.zeros(2, 1))["terminated"].tolist() == [True, False]
    td = env.step(torch.tensor([[float("nan")], [1.0]]))  # row 0 is reset, its action unused
    assert td["is_init"].tolist() == [True, False]
    assert bool(td["observation"].isfinite().all())
    assert td["reward"][0] == 0 and td["duration"][0] == 0 and not td["terminated"][0]


def test_wrong_action_shape_raises():
    env = ShipSteeringEnv(seeds=[0], envs_per_learner=2)
    env.reset()
    with pytest.raises(ValueError, match="shape"):
        env.step(torch.zeros(3))


def test_random_start_distribution():
    env = ShipSteeringEnv(seeds=[1, 2], envs_per_learner=500)
    obs = env.reset()["observation"]
    low, high = torch.tensor([0, 0, -180, -15.0]), torch.tensor([1000, 1000, 180, 15.0])
    assert torch.all((obs >= low) & (obs <= high))
    assert torch.all((obs.mean(0) - (low + high) / 2).abs() < 0.03 * (high - low))
    assert torch.all((obs.std(0) - (high - low) / 12**0.5).abs() < 0.03 * (high - low))


def test_truncation_after_max_episode_steps():
    env = ShipSteeringEnv(seeds=[0], envs_per_learner=2, max_episode_steps=4)
    env.reset_to(torch.tensor([500.0, 500.0, 0.0, 0.0]))
    flags = []
    for _ in range(5):
        td = env.step(torch.zeros(2, 1))
        flags.append((bool(td["truncated"][0]), bool(td["terminated"][0]), bool(td["is_init"][0])))
    assert flags == [(False, False, False)] * 3 + [(True, False, False), (False, False, True)]


def test_population_matches_separate_runs():
    together = ShipSteeringEnv(seeds=[3, 4], envs_per_learner=2)
    alone = ShipSteeringEnv(seeds=[4], envs_per_learner=2)
    a, b = together.reset(), alone.reset()
    assert torch.equal(a["observation"][2:], b["observation"])
    a = together.step(torch.full((4, 1), 5.0))
    b = alone.step(torch.full((2, 1), 5.0))
    assert torch.equal(a["observation"][2:], b["observation"])


def test_fixed_start_used_by_every_reset():
    env = ShipSteeringEnv(seeds=[0], envs_per_learner=2, fixed_start=FIGURE_5_12_STARTS)
    assert torch.equal(env.reset()["observation"], FIGURE_5_12_STARTS)


def test_params_change_the_dynamics():
    slow = ship_dynamics(
        torch.tensor([[0.0, 0.0, 0.0, 0.0]]), torch.zeros(1), ShipParams(speed=1.0)
    )
    assert slow[0, 1].item() == pytest.approx(0.2)


@pytest.mark.filterwarnings("ignore:.*symmetric and normalized")  # [-15, 15] deg/s is the text's
def test_gymnasium_check_env():
    env = gymnasium.make("hrl/ShipSteering-v0")
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert reward == -1.0 and info["duration"] == pytest.approx(0.6)


def test_torchrl_check_env_specs():
    check_env_specs(TorchRLEnv(ShipSteeringEnv(seeds=[0, 1], envs_per_learner=3)))
