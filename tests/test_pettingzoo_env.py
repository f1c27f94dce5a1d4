"""The PettingZoo adapters of ``hrl_torch.env.pettingzoo_env`` on the toys of helpers_multiagent."""

import random
import warnings

import numpy as np
import pytest
import torch
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test

from hrl_torch.env.pettingzoo_env import MultiAgentAECEnv, MultiAgentParallelEnv, make_aec
from tests.helpers_multiagent import AsyncToyEnv, SyncToyEnv

TOYS = [AsyncToyEnv, SyncToyEnv]


@pytest.fixture(autouse=True)
def _quiet():
    # api_test recommends Box or Discrete observations; Dict observations are the design here
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Observation is not a NumPy array")
        warnings.filterwarnings("ignore", "Observation space for each agent probably should")
        yield


# ------------------------------------------------------------------ PettingZoo's own checks
@pytest.mark.parametrize("toy", TOYS)
def test_aec_api_test(toy):
    api_test(MultiAgentAECEnv(toy, seed=3), num_cycles=200)
    api_test(make_aec(toy, seed=4), num_cycles=200)


@pytest.mark.parametrize("toy", TOYS)
def test_aec_seed_test(toy):
    seed_test(lambda: MultiAgentAECEnv(toy, seed=1), num_cycles=50)


def test_parallel_api_and_seed_test():
    parallel_api_test(MultiAgentParallelEnv(SyncToyEnv, seed=3), num_cycles=200)
    parallel_seed_test(lambda: MultiAgentParallelEnv(SyncToyEnv, seed=1), num_cycles=50)


def test_spaces():
    env = MultiAgentAECEnv(AsyncToyEnv)
    assert env.possible_agents == ["agent_0", "agent_1", "agent_2"]
    space = env.observation_space("agent_1")
    assert set(space.spaces) == {"last_action", "remaining", "clock", "target"}
    assert space["last_action"].n == 3 and space["target"].n == 3 and space["clock"].n == 9
    assert space["remaining"].shape == () and space["remaining"].dtype == np.float32
    assert env.action_space("agent_2").n == 3
    assert env.observation_space("agent_0") is not env.observation_space("agent_1")
    env.reset(seed=0)
    assert "completed" in env.infos["agent_0"]  # an undeclared shared field: a metric


# ------------------------------------------------------------------ AEC turn order by hand
def test_aec_turn_order_and_smdp_rewards():
    """Action ``a`` takes ``a + 1`` time units; completing it earns ``a + 1`` (+10 at target).

    The hand-written schedule (horizon 6, each epoch jumps to the next action end):

    =====  =====  ==============  ===================  ========================
    epoch  clock  acting          actions              actions that end (dt=1)
    =====  =====  ==============  ===================  ========================
    e0     0      0, 1, 2         0:a2  1:a0  2:a1     1 (a0)
    e1     1      1               1:a1                 2 (a1)
    e2     2      2               2:a0                 0 (a2), 1 (a1), 2 (a0)
    e3     3      0, 1, 2         0:a0  1:a2  2:a1     0 (a0)
    e4     4      0               0:a2                 2 (a1)
    e5     5      2               2:a2                 1 (a2); clock 6: terminated
    e6     6      everyone (cut)  dead steps (None)
    =====  =====  ==============  ===================  ========================
    """
    env = MultiAgentAECEnv(AsyncToyEnv, seed=0)
    env.reset(seed=0)
    target = int(env.observe("agent_0")["target"])
    r = {a: a + 1 + 10 * (a == target) for a in range(3)}  # team reward of finishing a
    team = [r[0], r[1], r[2] + r[1] + r[0], r[0], r[1], r[2]]  # team reward of e0..e5
    # (agent, action, reward last() returns at its turn, duration in its info, clock)
    schedule = [
        ("agent_0", 2, 0, 0, 0),
        ("agent_1", 0, 0, 0, 0),
        ("agent_2", 1, 0, 0, 0),
        ("agent_1", 1, team[0], 1, 1),
        ("agent_2", 0, team[0] + team[1], 2, 2),
        ("agent_0", 0, team[0] + team[1] + team[2], 3, 3),
        ("agent_1", 2, team[1] + team[2], 2, 3),
        ("agent_2", 1, team[2], 1, 3),
        ("agent_0", 2, team[3], 1, 4),
        ("agent_2", 2, team[3] + team[4], 2, 5),
        ("agent_0", None, team[4] + team[5], 2, 6),  # dead steps: every agent's share
        ("agent_1", None, team[3] + team[4] + team[5], 3, 6),
        ("agent_2", None, team[5], 1, 6),
    ]
    for agent, action, reward, duration, clock in schedule:
        assert env.agent_selection == agent
        obs, got, terminated, truncated, info = env.last()
        assert got == reward, agent
        assert info["duration"] == duration
        assert int(obs["clock"]) == clock
        assert terminated == (clock == 6) and not truncated
        env.step(action)
    assert env.agents == [] and env.epochs == 6


def test_each_agent_sees_the_team_return_once():
    env = MultiAgentAECEnv(AsyncToyEnv, seed=5)
    rng = random.Random(0)
    for _ in range(3):
        env.reset()
        seen = dict.fromkeys(env.possible_agents, 0.0)
        team = 0.0
        for agent in env.agent_iter():
            _, reward, terminated, truncated, _ = env.last()
            seen[agent] += reward
            epochs = env.epochs
            env.step(None if terminated or truncated else rng.randrange(3))
            if env.epochs > epochs:  # this action stepped the batched env
                team += env.infos[env.agents[0]]["team_reward"]
        assert all(v == pytest.approx(team) for v in seen.values())


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("action", [3, -1, 1.5, None, "1", np.array([1, 2])])
def test_invalid_action_is_one_line_value_error(action):
    env = MultiAgentAECEnv(AsyncToyEnv)
    env.reset(seed=0)
    env.step(1)
    with pytest.raises(
        ValueError, match=r"invalid action .* for agent_1: expected an integer"
    ) as e:
        env.step(action)
    assert "\n" not in str(e.value)
    assert env.agent_selection == "agent_1"  # nothing changed: the turn goes on
    env.step(np.int32(2))
    assert env.agent_selection == "agent_2"


def test_parallel_invalid_action_and_missing_agent():
    env = MultiAgentParallelEnv(SyncToyEnv)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="invalid action 7 for agent_1"):
        env.step({"agent_0": 0, "agent_1": 7})
    with pytest.raises(ValueError, match=r"missing \['agent_1'\]"):
        env.step({"agent_0": 0})


def test_parallel_refuses_asynchronous_env():
    env = MultiAgentParallelEnv(AsyncToyEnv)
    env.reset(seed=0)
    with pytest.raises(RuntimeError, match="asynchronous.*use MultiAgentAECEnv") as e:
        env.step({"agent_0": 2, "agent_1": 0, "agent_2": 1})
    assert "\n" not in str(e.value)


def test_step_after_the_end_asks_for_reset():
    env = MultiAgentParallelEnv(SyncToyEnv)
    env.reset(seed=0)
    while env.agents:
        env.step(dict.fromkeys(env.agents, 1))  # everyone stays: truncated at 20 steps
    with pytest.raises(RuntimeError, match="call reset"):
        env.step({})


# ------------------------------------------------------------------ same as the batched env
def _aec_run(toy, seed, actions):
    """The AEC env's view after each batched step of ``actions [T, n]`` (one row).

    The batched env's auto-reset step (after an end) is the AEC env's dead steps plus ``reset()``.
    """
    env = MultiAgentAECEnv(toy, seed=seed)
    env.reset()
    out = []
    for joint in actions.tolist():
        if any(env.terminations.values()) or any(env.truncations.values()):
            while env.agents:
                env.step(None)
            env.reset()
        else:
            epochs = env.epochs
            while env.epochs == epochs:
                agent = env.agent_selection
                env.step(joint[env.possible_agents.index(agent)])
        out.append(({a: env.observe(a) for a in env.possible_agents}, dict(env.rewards)))
    return out


@pytest.mark.parametrize("toy", TOYS)
def test_aec_matches_batched_env(toy):
    """Row 0 of a batched population (seeds 7 and 99) and the AEC env with seed 7 agree."""
    seed, steps = 7, 40
    batched = toy([seed, 99], 1)
    n = batched.n_agents
    actions = torch.randint(0, 3, (steps, 2, n), generator=torch.Generator().manual_seed(0))
    batched.reset()
    expected = [batched.step(actions[t])[0] for t in range(steps)]
    got = _aec_run(toy, seed, actions[:, 0])
    assert sum(bool(td["is_init"]) for td in expected) >= 2  # several episodes
    for td, (obs, rewards) in zip(expected, got, strict=True):
        for j, agent in enumerate(sorted(obs)):
            for key, value in obs[agent].items():
                source = td["agents", key][j] if key in td["agents"].keys() else td[key]
                np.testing.assert_array_equal(value, source.numpy())
            assert rewards[agent] == float(td["agents", "reward"][j])


def test_aec_truncation():
    def factory(seeds, envs_per_learner):
        return AsyncToyEnv(seeds, envs_per_learner, horizon=100, max_episode_steps=3)

    api_test(MultiAgentAECEnv(factory), num_cycles=50)
    env = MultiAgentAECEnv(factory)
    env.reset(seed=0)
    while env.epochs < 3:
        env.step(1)  # every action takes 2 units: all agents act at every epoch
    assert all(env.truncations.values()) and not any(env.terminations.values())
    assert env.agent_selection == "agent_0"
    for agent in ("agent_0", "agent_1", "agent_2"):
        assert env.agent_selection == agent
        env.step(None)
    assert env.agents == []


def test_plain_benchmark_helper_counts_epochs():
    from benchmarks.plain_pettingzoo import steps_per_second

    assert steps_per_second(lambda: make_aec(AsyncToyEnv), 30) > 0
