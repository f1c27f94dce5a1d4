import collections

import gymnasium
import pytest
import torch
from gymnasium.utils.env_checker import check_env as gymnasium_check_env

import envs  # noqa: F401  (registers hrl/FourRooms-v0)
from agents.four_rooms import DOMAIN, OPTIMAL, four_rooms_hierarchy
from envs.four_rooms import (
    CELLS,
    GOALS,
    N_STATES,
    FourRoomsEnv,
    decode,
    encode,
    region_of,
    transition_tables,
)
from envs.grid import EAST, NORTH, SOUTH, WEST, optimal_values
from hrl_torch.env.envcheck import check_env

A, B, C, D = range(4)


def _step_from(state: int, action: int):
    env = FourRoomsEnv([0], 1)
    env.reset()
    env.state = torch.tensor([state])
    td = env.step(torch.tensor([action]))
    fields = decode(td["observation"])
    return td, (int(fields["row"][0]), int(fields["col"][0]), int(fields["goal"][0]))


@pytest.mark.parametrize(
    ("start", "action", "after", "terminated"),
    [
        # (row, col, goal)
        ((2, 2, D), NORTH, (1, 2, D), False),
        ((1, 2, D), NORTH, (1, 2, D), False),  # outer wall
        ((2, 5, D), EAST, (2, 5, D), False),  # the wall between the top rooms
        ((3, 5, D), EAST, (3, 6, D), False),  # into hallway 0
        ((3, 6, D), EAST, (3, 7, D), False),  # out of it, into the top-right room
        ((3, 6, D), NORTH, (3, 6, D), False),  # a hallway's side walls
        ((5, 2, D), SOUTH, (6, 2, D), False),  # hallway 1
        ((6, 9, D), SOUTH, (7, 9, D), False),  # hallway 2
        ((10, 5, D), EAST, (10, 6, D), False),  # hallway 3
        ((1, 2, A), WEST, (1, 1, A), True),  # onto goal A
        ((11, 10, D), EAST, (11, 11, D), True),  # onto goal D
        ((11, 10, C), EAST, (11, 11, C), False),  # D's cell is not C's goal
    ],
)
def test_hand_checked_transitions(start, action, after, terminated):
    td, got = _step_from(encode(*start), action)
    assert got == after
    assert td["reward"].item() == -1.0
    assert bool(td["terminated"][0]) is terminated


def test_layout_rooms_and_starts():
    assert len(CELLS) == 104 and N_STATES == 416
    rooms = collections.Counter(region_of(r, c) for r, c in CELLS)
    assert rooms == {0: 25, 1: 30, 2: 25, 3: 20, 4: 1, 5: 1, 6: 1, 7: 1}
    next_state, reward, terminated, starts = transition_tables()
    assert next_state.shape == reward.shape == terminated.shape == (416, 4)
    assert starts.numel() == 103 * 4  # every cell but the goal's, for each goal
    fields = decode(starts)
    for g, (row, col) in enumerate(GOALS):  # no episode starts on its goal
        on_goal = (fields["goal"] == g) & (fields["row"] == row) & (fields["col"] == col)
        assert not bool(on_goal.any())


def test_shortest_paths():
    value = optimal_values(*transition_tables()[:3])
    assert value[encode(1, 2, A)] == -1.0
    assert value[encode(3, 5, B)] == -(1 + 2 + 5)  # through hallway 0, then up and right
    assert value[encode(11, 11, A)] == -20.0  # the far corner: the longest shortest path
    assert float(value[transition_tables()[3]].min()) == -20.0
    # the evaluation episodes' optimum (the domain's reference)
    assert OPTIMAL == pytest.approx(-11.05)


def test_population_equals_separate_runs_and_contract():
    env = FourRoomsEnv([0], 2)
    check_env(env, four_rooms_hierarchy(), make_env=FourRoomsEnv, steps=48)
    for algo in DOMAIN.algos:
        check_env(DOMAIN.make_env([0], 2), DOMAIN.algos[algo].make_graph(), steps=16)


def test_gymnasium_registration():
    gymnasium_check_env(gymnasium.make("hrl/FourRooms-v0").unwrapped, skip_render_check=True)
