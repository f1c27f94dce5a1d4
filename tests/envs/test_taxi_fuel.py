import gymnasium
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from torchrl.envs.utils import check_env_specs

import envs  # noqa: F401  (registers hrl/TaxiFuel-v0)
from envs import taxi
from envs.taxi_fuel import (
    CAPACITY,
    DROPOFF,
    EAST,
    FILLUP,
    N_ACTIONS,
    N_STATES,
    PICKUP,
    SOUTH,
    TaxiFuelEnv,
    decode,
    encode,
    transition_tables,
)
from hrl_torch.env.torchrl_env import TorchRLEnv

IN_TAXI = 4
R, G, Y, B = range(4)


def _step_from(state: int, action: int):
    env = TaxiFuelEnv(seeds=[0], envs_per_learner=1)
    env.reset()
    env.state = torch.tensor([state])
    td = env.step(torch.tensor([action]))
    return td, {k: int(v[0]) for k, v in decode(td["observation"]).items()}


@pytest.mark.parametrize(
    ("start", "action", "after", "reward", "terminated"),
    [
        # (row, col, passenger, destination, fuel)
        ((0, 0, G, Y, 5), SOUTH, (1, 0, G, Y, 4), -1, False),
        ((0, 1, G, Y, 5), EAST, (0, 1, G, Y, 4), -1, False),  # into the wall: fuel still spent
        ((3, 2, G, Y, 4), FILLUP, (3, 2, G, Y, CAPACITY), -1, False),  # at F
        ((3, 2, G, Y, 12), FILLUP, (3, 2, G, Y, 12), -1, False),  # full tank: legal, no effect
        ((0, 0, G, Y, 4), FILLUP, (0, 0, G, Y, 4), -10, False),  # away from F: illegal
        ((0, 0, R, Y, 0), PICKUP, (0, 0, IN_TAXI, Y, 0), -1, False),  # no fuel needed
        ((0, 0, G, Y, 3), PICKUP, (0, 0, G, Y, 3), -10, False),  # illegal pickup
        ((4, 0, IN_TAXI, Y, 2), DROPOFF, (4, 0, Y, Y, 2), 20, True),  # delivery
        ((4, 0, IN_TAXI, B, 2), DROPOFF, (4, 0, Y, B, 2), -1, False),  # wrong station
        ((2, 2, IN_TAXI, B, 0), SOUTH, (3, 2, IN_TAXI, B, 0), -20, True),  # runs dry
    ],
)
def test_hand_checked_transitions(start, action, after, reward, terminated):
    td, fields = _step_from(encode(*start), action)
    got = (
        fields["taxi_row"],
        fields["taxi_col"],
        fields["passenger"],
        fields["destination"],
        fields["fuel"],
    )
    assert got == after
    assert td["reward"].item() == reward
    assert bool(td["terminated"][0]) is terminated
    assert bool(td["out_of_fuel"][0]) is (reward == -20)


def test_encoding_and_table_sizes():
    assert N_STATES == 13 * 500 == 6_500
    next_state, reward, terminated, starts = transition_tables()
    assert next_state.shape == reward.shape == terminated.shape == (N_STATES, N_ACTIONS)
    assert int(next_state.min()) >= 0 and int(next_state.max()) < N_STATES
    assert starts.numel() == 8 * 300 and starts.unique().numel() == 2_400
    s = encode(2, 3, B, G, 7)
    assert s == 7 * 500 + taxi.encode(2, 3, B, G)
    fields = decode(torch.tensor(s))
    assert [
        int(fields[k]) for k in ("taxi_row", "taxi_col", "passenger", "destination", "fuel")
    ] == [2, 3, B, G, 7]
    # without fuel the tables are the taxi's
    taxi_next, taxi_reward, _, _ = taxi.transition_tables()
    full = CAPACITY * 500 + torch.arange(500)
    assert torch.equal(next_state[full, PICKUP] % 500, taxi_next[:, PICKUP])
    assert torch.equal(reward[full, :6], taxi_reward)


def test_start_distribution():
    env = TaxiFuelEnv(seeds=[0, 1], envs_per_learner=2_000)
    td = env.reset()
    fuel = td["fuel"]
    assert int(fuel.min()) == 5 and int(fuel.max()) == 12
    counts = torch.bincount(fuel, minlength=13)[5:].float()
    assert torch.all((counts / 4_000 - 1 / 8).abs() < 0.02)
    assert torch.all(td["passenger"] < 4) and torch.all(td["passenger"] != td["destination"])


def test_fuel_accounting_under_random_actions():
    env = TaxiFuelEnv(seeds=[5], envs_per_learner=512)
    rng = torch.Generator().manual_seed(0)
    td = env.reset()
    n_terminated = 0
    for _ in range(60):
        action = torch.randint(0, N_ACTIONS, (512,), generator=rng)
        nxt = env.step(action)
        live = ~nxt["is_init"]
        fuel, new = td["fuel"], nxt["fuel"]
        at_f = td["taxi_loc"] == 3 * 5 + 2
        expected = torch.where(action < PICKUP, (fuel - 1).clamp_min(0), fuel)
        expected = torch.where((action == FILLUP) & at_f, torch.tensor(CAPACITY), expected)
        assert torch.equal(new[live], expected[live])
        dry = (action < PICKUP) & (fuel == 0) & live
        assert torch.equal(nxt["out_of_fuel"][live], dry[live])
        assert torch.all(nxt["terminated"][dry]) and torch.all(nxt["reward"][dry] == -20)
        n_terminated += int(nxt["terminated"].sum())
        td = nxt
    assert n_terminated > 0


def test_episode_end_and_time_limit():
    env = TaxiFuelEnv(seeds=[0], envs_per_learner=1, max_episode_steps=3)
    env.reset()
    env.state = torch.tensor([encode(3, 2, G, Y, 5)])
    flags = [bool(env.step(torch.tensor([FILLUP]))["truncated"][0]) for _ in range(4)]
    assert flags == [False, False, True, False]
    assert TaxiFuelEnv().max_episode_steps == 200
    # a dry taxi ends the episode; the next step starts a new one
    env = TaxiFuelEnv(seeds=[0], envs_per_learner=1)
    env.reset()
    env.state = torch.tensor([encode(2, 2, G, Y, 0)])
    assert bool(env.step(torch.tensor([SOUTH]))["terminated"][0])
    td = env.step(torch.tensor([SOUTH]))
    assert bool(td["is_init"][0]) and td["reward"].item() == 0 and int(td["fuel"][0]) >= 5


def test_invalid_action():
    env = TaxiFuelEnv()
    env.reset()
    with pytest.raises(ValueError):
        env.step(torch.tensor([7]))


def test_gymnasium_check_env():
    env = gymnasium.make("hrl/TaxiFuel-v0")
    check_env(env.unwrapped, skip_render_check=True)
    assert env.action_space.n == 7
    assert env.observation_space["observation"].n == N_STATES


def test_torchrl_check_env_specs():
    check_env_specs(TorchRLEnv(TaxiFuelEnv(seeds=[0, 1], envs_per_learner=3)))
