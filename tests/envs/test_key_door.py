import gymnasium
import pytest
import torch
from gymnasium.utils.env_checker import check_env as gymnasium_check_env

import envs  # noqa: F401  (registers hrl/KeyDoor-v0)
from agents.key_door import DOMAIN, OPTIMAL, key_door_hierarchy
from envs.grid import optimal_values
from envs.key_door import (
    EAST,
    HELD,
    NORTH,
    PICKUP,
    SOUTH,
    UNLOCK,
    USED,
    WEST,
    KeyDoorEnv,
    decode,
    encode,
    transition_tables,
)
from hrl_torch.env.envcheck import check_env


def _step_from(state: int, action: int):
    env = KeyDoorEnv([0], 1)
    env.reset()
    env.state = torch.tensor([state])
    td = env.step(torch.tensor([action]))
    f = {k: int(v[0]) for k, v in decode(td["observation"]).items()}
    return td, (f["row"], f["col"], f["key"], f["goal"])


@pytest.mark.parametrize(
    ("start", "action", "after", "reward", "terminated"),
    [
        # (row, col, key, goal); key 0-3 on spot (0,0), (4,0), (0,2), (4,2); 4 held; 5 used
        ((1, 0, 0, 0), NORTH, (0, 0, 0, 0), -1, False),
        ((0, 0, 0, 0), PICKUP, (0, 0, HELD, 0), -1, False),  # on its spot
        ((0, 0, 1, 0), PICKUP, (0, 0, 1, 0), -10, False),  # the key is on (4, 0)
        ((4, 2, 3, 1), PICKUP, (4, 2, HELD, 1), -1, False),
        ((0, 0, HELD, 0), PICKUP, (0, 0, HELD, 0), -10, False),  # already held
        ((2, 3, 0, 0), EAST, (2, 3, 0, 0), -1, False),  # the locked door
        ((2, 3, 0, 0), UNLOCK, (2, 3, 0, 0), -10, False),  # without the key
        ((2, 2, HELD, 0), UNLOCK, (2, 2, HELD, 0), -10, False),  # away from the door
        ((2, 3, HELD, 0), UNLOCK, (2, 3, USED, 0), -1, False),
        ((2, 3, USED, 0), EAST, (2, 4, USED, 0), -1, False),  # through the open door
        ((2, 4, USED, 0), NORTH, (2, 4, USED, 0), -1, False),  # the door cell's side walls
        ((1, 3, USED, 0), EAST, (1, 3, USED, 0), -1, False),  # the wall
        ((0, 7, USED, 0), EAST, (0, 8, USED, 0), -1, True),  # goal 0
        ((0, 7, USED, 1), EAST, (0, 8, USED, 1), -1, False),  # goal 1 is (4, 8)
        ((3, 8, USED, 1), SOUTH, (4, 8, USED, 1), -1, True),
        ((3, 0, 2, 1), WEST, (3, 0, 2, 1), -1, False),  # outer wall
    ],
)
def test_hand_checked_transitions(start, action, after, reward, terminated):
    td, got = _step_from(encode(*start), action)
    assert got == after
    assert td["reward"].item() == reward
    assert bool(td["terminated"][0]) is terminated


def test_tables_starts_and_optimum():
    next_state, reward, terminated, starts = transition_tables()
    assert next_state.shape == reward.shape == terminated.shape == (492, 6)
    fields = decode(starts)
    assert starts.numel() == 160
    assert bool((fields["col"] < 4).all()) and bool((fields["key"] < HELD).all())
    value = optimal_values(next_state, reward, terminated)
    # from (2, 3), key on (0, 2), goal (0, 8): 3 moves, pickup, 3 moves, unlock, 5 moves east
    # and 2 north (the last one onto the goal)
    assert value[encode(2, 3, 2, 0)] == -(3 + 1 + 3 + 1 + 7)
    assert float(value[starts].min()) == -21.0 and float(value[starts].max()) == -12.0
    eval_starts = KeyDoorEnv([DOMAIN.eval_seed], 100).reset()["observation"]
    assert OPTIMAL == pytest.approx(float(value[eval_starts].mean())) == -16.5


def test_population_equals_separate_runs_and_contract():
    check_env(KeyDoorEnv([0], 2), key_door_hierarchy(), make_env=KeyDoorEnv, steps=48)
    for algo in DOMAIN.algos:
        check_env(DOMAIN.make_env([0], 2), DOMAIN.algos[algo].make_graph(), steps=16)


def test_gymnasium_registration():
    gymnasium_check_env(gymnasium.make("hrl/KeyDoor-v0").unwrapped, skip_render_check=True)
