"""Taxi-fuel as the text sets it: 8,750 states, its rules, and average reward per step."""

import itertools

import pytest
import torch

from envs import taxi_fuel
from envs.taxi_fuel import DROPOFF, FILLUP, PICKUP, SOUTH
from envs.taxi_fuel_text import (
    CAPACITY,
    FACTORS,
    N_STATES,
    TaxiFuelTextEnv,
    decode,
    encode,
    reachable,
    transition_tables,
)

IN_TAXI = 4
R, G, Y, B = range(4)
FIELDS = ("taxi_row", "taxi_col", "passenger", "destination", "fuel")


def test_the_state_index_has_the_texts_8750_states():
    env = TaxiFuelTextEnv([0], 1)
    size = env.observation_sizes["observation"]
    fields = decode(torch.arange(size))
    tuples = {tuple(int(fields[k][s]) for k in FIELDS) for s in range(size)}
    assert len(tuples) == size == N_STATES  # one state per index, every index a state
    assert size == 8_750
    assert [FACTORS[k] for k in FACTORS] == [25, 5, 5, 14]
    assert sorted({t[4] for t in tuples}) == list(range(-1, CAPACITY + 1))  # 14 fuel levels
    for t in itertools.islice(sorted(tuples), 0, None, 97):
        assert encode(*t) == int(fields["observation"][encode(*t)])
        assert tuple(int(fields[k][encode(*t)]) for k in FIELDS) == t
    with pytest.raises(ValueError, match="fuel_level"):
        encode(0, 0, R, G, CAPACITY + 1)
    with pytest.raises(ValueError, match="square"):
        encode(0, 5, R, G, 3)


def test_reachable_states_and_starts():
    nxt, reward, terminated, starts = transition_tables()
    start = decode(starts)
    assert starts.numel() == 25 * 12 * 8 == 2_400
    assert int(start["fuel"].min()) == 5 and int(start["fuel"].max()) == 12
    assert bool((start["passenger"] != start["destination"]).all())
    seen = reachable()
    fields = decode(torch.arange(N_STATES)[seen])
    assert int(seen.sum()) == 5_475  # measured: the rest is the unused destination code and
    assert int(fields["destination"].max()) == 3  # unreachable fuel/passenger pairings
    assert bool((fields["fuel"] == -1).any())  # the level below zero is met (and ends it)


def _step_from(start, action):
    env = TaxiFuelTextEnv(seeds=[0], envs_per_learner=1)
    env.reset()
    env.state = torch.tensor([encode(*start)])
    td = env.step(torch.tensor([action]))
    fields = decode(td["observation"])
    return td, tuple(int(fields[k][0]) for k in FIELDS)


@pytest.mark.parametrize(
    ("start", "action", "after", "reward", "terminated"),
    [
        ((0, 0, G, Y, 5), SOUTH, (1, 0, G, Y, 4), -1, False),
        ((3, 2, G, Y, 4), FILLUP, (3, 2, G, Y, CAPACITY), -1, False),  # at F
        ((0, 0, G, Y, 4), FILLUP, (0, 0, G, Y, 4), -1, False),  # away from F: -1, not -10
        ((0, 0, G, Y, 3), PICKUP, (0, 0, G, Y, 3), -10, False),  # illegal pickup
        ((4, 0, IN_TAXI, Y, 0), DROPOFF, (4, 0, Y, Y, 0), 20, True),  # delivery
        ((4, 0, IN_TAXI, B, 2), DROPOFF, (4, 0, IN_TAXI, B, 2), -10, False),  # wrong station
        ((2, 2, IN_TAXI, B, 2), DROPOFF, (2, 2, IN_TAXI, B, 2), -10, False),  # no station
        ((2, 2, IN_TAXI, B, 0), SOUTH, (3, 2, IN_TAXI, B, -1), -20, True),  # below zero: -1
    ],
)
def test_hand_checked_transitions(start, action, after, reward, terminated):
    td, got = _step_from(start, action)
    assert got == after
    assert td["reward"].item() == reward
    assert bool(td["terminated"][0]) is terminated
    assert bool(td["out_of_fuel"][0]) is (reward == -20)


def test_the_rest_of_the_rules_are_taxi_fuels():
    # every taxi-fuel-earlier state and action: the same successor, reward and end, except the three
    # rules the text changes (Fillup away from F; Dropoff at a wrong station; below zero)
    old_next, old_reward, old_term, _ = taxi_fuel.transition_tables()
    old = taxi_fuel.decode(torch.arange(taxi_fuel.N_STATES))
    new_index = torch.tensor(
        [encode(*(int(old[k][s]) for k in FIELDS)) for s in range(taxi_fuel.N_STATES)]
    )
    nxt, reward, terminated, _ = transition_tables()
    changed = (old_reward == -10) & (torch.arange(7) == FILLUP)
    aboard = old["passenger"][:, None] == IN_TAXI
    wrong_drop = aboard & (torch.arange(7) == DROPOFF) & (old_reward == -1)
    dry = old_reward == -20
    same = ~changed & ~dry & ~wrong_drop
    assert torch.equal(nxt[new_index][wrong_drop], new_index[:, None].expand(-1, 7)[wrong_drop])
    assert bool((reward[new_index][wrong_drop] == -10).all())
    assert int(wrong_drop.sum()) == 13 * 3 * 4  # fuel x the other stations x destinations
    assert torch.equal(nxt[new_index][same], new_index[old_next][same])
    assert torch.equal(reward[new_index][same], old_reward[same])
    assert torch.equal(terminated[new_index], old_term)
    assert bool((reward[new_index][changed] == -1).all())
    assert int(changed.sum()) == 13 * 24 * 20  # every state off F
    assert bool((decode(nxt[new_index][dry])["fuel"] == -1).all())


def test_no_time_limit():
    env = TaxiFuelTextEnv([0], 4)
    env.reset()
    env.state = torch.full((4,), encode(3, 2, G, Y, CAPACITY))  # Fillup at F, full: a loop
    for _ in range(500):
        td = env.step(torch.full((4,), FILLUP))
        assert not bool(td["truncated"].any() or td["terminated"].any())
    assert env.max_episode_steps is None


def _greedy_policy() -> torch.Tensor:
    """The return-optimal policy by value iteration (independent of the script's bisection)."""
    nxt, reward, terminal, _ = transition_tables()
    v = torch.zeros(N_STATES, dtype=torch.float64)
    for _ in range(300):
        q = reward.double() + torch.where(terminal, 0.0, v[nxt])
        v = q.max(1).values
    return q.argmax(1)


def test_reward_per_step_of_the_optimal_policy_is_the_optimal_gain():
    # episodes one after the other: a reset step has neither reward nor time, so the
    # average reward per step of the run is E[return] / E[length] (renewal reward); counted
    # over whole episodes (a run cut mid-episode lacks that episode's +20)
    from scripts.fig_5_3_taxi_fuel_text import optimal_gain

    gain = optimal_gain(tol=1e-4)
    assert gain == pytest.approx(0.3177, abs=2e-4)  # measured: 5.063 / 15.94 steps
    policy = _greedy_policy()
    env = TaxiFuelTextEnv([3], 256)
    td = env.reset()
    ret, length = torch.zeros(256), torch.zeros(256)
    total, time = 0.0, 0.0
    for _ in range(400):
        td = env.step(policy[td["observation"]])
        ret, length = ret + td["reward"], length + td["duration"]
        done = td["terminated"]
        total, time = total + float(ret[done].sum()), time + float(length[done].sum())
        ret, length = ret.masked_fill(done, 0.0), length.masked_fill(done, 0.0)
    assert total / time == pytest.approx(gain, abs=0.02)
