import gymnasium
import numpy as np
import torch
from gymnasium.utils.env_checker import check_env
from torchrl.envs.utils import check_env_specs

import envs  # noqa: F401  (registers hrl/ ids)
from envs.taxi import TaxiEnv, decode, transition_tables
from hrl_torch.env.torchrl_env import TorchRLEnv


def gym_taxi():
    return gymnasium.make("Taxi-v4").unwrapped


def test_transition_table_equals_gymnasium_for_every_state_and_action():
    next_state, reward, terminated, _ = transition_tables()
    P = gym_taxi().P
    for s in range(500):
        for a in range(6):
            ((prob, s2, r, done),) = P[s][a]
            assert prob == 1.0
            assert (int(next_state[s, a]), float(reward[s, a]), bool(terminated[s, a])) == (
                s2,
                r,
                done,
            ), (s, a)


def test_start_distribution_equals_gymnasium():
    _, _, _, starts = transition_tables()
    dist = gym_taxi().initial_state_distrib
    assert sorted(starts.tolist()) == np.flatnonzero(dist).tolist()
    assert np.allclose(dist[dist > 0], 1 / 300)
    # the batched env samples every start state, roughly uniformly
    env = TaxiEnv([0], 30_000)
    counts = torch.bincount(env.reset()["observation"], minlength=500)
    assert set(counts.nonzero().squeeze(1).tolist()) == set(starts.tolist())
    assert counts[starts].float().std() / counts[starts].float().mean() < 0.15


def test_batched_steps_follow_gymnasium_trajectories():
    rng = np.random.default_rng(0)
    env = TaxiEnv([0, 1], 8)
    state = env.reset()["observation"]
    gyms = [gymnasium.make("Taxi-v4") for _ in range(16)]
    for g, s in zip(gyms, state.tolist(), strict=True):
        g.reset(seed=0)
        g.unwrapped.s = s
    for _ in range(60):
        action = torch.as_tensor(rng.integers(0, 6, 16))
        td = env.step(action)
        for b, g in enumerate(gyms):
            if bool(td["is_init"][b]):
                g.unwrapped.s = int(td["observation"][b])
                continue
            s2, r, term, _, _ = g.step(int(action[b]))
            assert (s2, r, term) == (
                int(td["observation"][b]),
                float(td["reward"][b]),
                bool(td["terminated"][b]),
            )


def test_time_limit_truncates_at_200_and_resets_next_step():
    env = TaxiEnv([0], 2)
    env.reset()
    north = torch.ones(2, dtype=torch.long)  # never terminates
    for _ in range(199):
        td = env.step(north)
        assert not td["truncated"].any()
    td = env.step(north)
    assert td["truncated"].all() and not td["terminated"].any()
    td = env.step(north)
    assert td["is_init"].all() and (td["reward"] == 0).all()


def test_decode_matches_gymnasium():
    g = gym_taxi()
    s = torch.arange(500)
    f = decode(s)
    for k in range(0, 500, 37):
        row, col, p, d = g.decode(k)
        assert (
            int(f["taxi_row"][k]),
            int(f["taxi_col"][k]),
            int(f["passenger"][k]),
            int(f["destination"][k]),
        ) == (row, col, p, d)


def test_invalid_action_is_a_clear_error():
    env = TaxiEnv([0], 2)
    env.reset()
    import pytest

    with pytest.raises(ValueError, match=r"action 6 outside the action space \[0, 6\)"):
        env.step(torch.tensor([0, 6]))


def test_checkers_pass():
    check_env(gymnasium.make("hrl/Taxi-v0").unwrapped, skip_render_check=True)
    check_env_specs(TorchRLEnv(TaxiEnv([0, 1], 3)))
