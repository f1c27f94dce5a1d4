import math

import pytest
import torch

from envs.taxi import decode as taxi_decode
from envs.taxi import encode as taxi_encode
from envs.taxi import transition_tables
from envs.two_taxi import (
    EAST,
    EMPTY,
    MOVES,
    N_ACTIONS,
    NO_PASSENGER,
    NORTH,
    PICKUP,
    PUTDOWN,
    SOUTH,
    STATION_LOC,
    WAIT,
    WEST,
    TwoTaxiEnv,
    average_wait,
    destination_of_code,
    station_code,
    throughput,
)

torch.set_num_threads(1)
R, G, Y, B = range(4)
NO_ARRIVALS = math.inf


def place(env, taxi_loc, status=(EMPTY, EMPTY), passengers=None):
    """Put the single row of ``env`` in a given state; ``passengers``: {station: destination}."""
    env.taxi_loc = torch.tensor([taxi_loc])
    env.status = torch.tensor([status])
    env.station_dest = torch.full((1, 4), NO_PASSENGER)
    env.station_age = torch.zeros(1, 4, dtype=torch.long)
    for station, dest in (passengers or {}).items():
        env.station_dest[0, station] = dest


def step(env, *actions):
    return env.step(torch.tensor([actions]))


def test_moves_are_those_of_the_taxi_map():
    next_state = transition_tables()[0]
    for loc in range(25):
        for action in (SOUTH, NORTH, EAST, WEST):
            s = taxi_encode(loc // 5, loc % 5, 0, 1)
            assert int(taxi_decode(next_state[s, action])["taxi_loc"]) == int(MOVES[loc, action])
        assert (MOVES[loc, PICKUP:] == loc).all()
    assert STATION_LOC.tolist() == [0, 4, 20, 23]


def test_station_codes_round_trip():
    dest = torch.tensor([[NO_PASSENGER, R, R, R], [G, NO_PASSENGER, G, G], [B, B, B, Y]])
    code = station_code(dest)
    assert code.tolist() == [[0, 1, 1, 1], [1, 0, 2, 2], [3, 3, 3, 3]]
    for s in range(4):
        others = [d for d in range(4) if d != s]
        for c, d in enumerate(others, start=1):
            assert int(destination_of_code(s, torch.tensor(c))) == d


def test_pickup_delivery_and_waiting_time_by_hand():
    env = TwoTaxiEnv([0], 1, mean_interarrival=NO_ARRIVALS)
    env.reset()
    place(env, [5, 12], passengers={R: G})  # taxi 0 one step south of R; a passenger R -> G
    td = step(env, NORTH, WAIT)
    assert td["agents", "taxi_loc"].tolist() == [[0, 12]]
    assert td["reward"].item() == -1.0  # one passenger waited this step
    assert td["waiting_R"].item() == 1 and td["n_waiting"].item() == 1
    td = step(env, PICKUP, WAIT)
    assert td["reward"].item() == -1.0 and td["n_picked_up"].item() == 1
    assert td["agents", "status"].tolist() == [[G, EMPTY]]
    assert td["agents", "picked_up"].tolist() == [[1, 0]]
    assert td["waiting_R"].item() == 0 and td["n_waiting"].item() == 0
    # R -> G: two south, four east, two north
    for action in (SOUTH, SOUTH, EAST, EAST, EAST, EAST, NORTH, NORTH):
        td = step(env, action, WAIT)
        assert td["reward"].item() == 0.0
    assert td["agents", "taxi_loc"].tolist() == [[4, 12]]
    td = step(env, PUTDOWN, WAIT)
    assert td["reward"].item() == 20.0 and td["n_delivered"].item() == 1
    assert td["wait_delivered"].item() == 2  # seen at the start, waited two steps to pickup
    assert td["agents", "delivered"].tolist() == [[1, 0]]
    assert td["agents", "status"].tolist() == [[EMPTY, EMPTY]]
    td = step(env, WAIT, WAIT)
    assert td["n_delivered"].item() == 0 and td["wait_delivered"].item() == 0


def test_pickup_race_goes_to_the_lowest_index_taxi():
    env = TwoTaxiEnv([0], 1, mean_interarrival=NO_ARRIVALS)
    env.reset()
    place(env, [23, 23], passengers={B: Y})
    td = step(env, PICKUP, PICKUP)
    assert td["agents", "status"].tolist() == [[Y, EMPTY]]
    assert td["reward"].item() == -1.0  # the loser's pickup was legal: no penalty
    assert td["n_picked_up"].item() == 1 and td["wait_delivered"].item() == 0


def test_illegal_pickups_and_putdowns():
    env = TwoTaxiEnv([0], 1, mean_interarrival=NO_ARRIVALS)
    env.reset()
    place(env, [0, 12], status=[G, EMPTY], passengers={R: Y})
    td = step(env, PICKUP, PICKUP)  # loaded taxi at R; empty taxi off the stations
    assert td["reward"].item() == -1.0 - 20.0
    assert td["waiting_R"].item() != 0 and td["agents", "status"].tolist() == [[G, EMPTY]]
    td = step(env, PUTDOWN, PUTDOWN)  # at R, not the destination G; an empty taxi
    assert td["reward"].item() == -1.0 - 20.0
    assert td["agents", "status"].tolist() == [[G, EMPTY]] and td["n_delivered"].item() == 0


@pytest.mark.parametrize("interarrival", [5, 10, 20])
def test_arrival_rate_is_one_per_mean_interarrival_steps(interarrival):
    n, steps = 4000, 100
    env = TwoTaxiEnv([0, 1], n // 2, mean_interarrival=interarrival)
    env.reset()
    wait = torch.full((n, 2), WAIT)
    arrived = torch.stack([env.step(wait)["n_arrived"] for _ in range(steps)])
    p = 1 / interarrival
    assert abs(arrived.double().mean().item() - p) < 4.5 * (p * (1 - p) / (n * steps)) ** 0.5


def test_arrivals_are_uniform_over_stations_and_other_destinations():
    n = 4000
    env = TwoTaxiEnv([3], n, mean_interarrival=2)
    env.reset()
    wait = torch.full((n, 2), WAIT)
    counts = torch.zeros(4, 5, dtype=torch.long)
    for _ in range(30):
        env.step(wait)
        dest = env.station_dest
        for s in range(4):
            counts[s] += torch.bincount(dest[:, s], minlength=5)
        env.station_dest.fill_(NO_PASSENGER)  # keep every station free
    pairs = counts[:, :4]
    assert (pairs.diagonal() == 0).all()
    off = pairs[~torch.eye(4, dtype=torch.bool)].double()
    expected = n * 30 / 2 / 12
    assert (off - expected).abs().max() < 4.5 * expected**0.5


def test_arrivals_at_occupied_stations_are_lost():
    n = 500
    env = TwoTaxiEnv([0], n, mean_interarrival=3)
    env.reset()
    env.station_dest = torch.tensor([[G, Y, B, R]]).repeat(n, 1)
    wait = torch.full((n, 2), WAIT)
    arrived = lost = 0
    for t in range(20):
        td = env.step(wait)
        arrived, lost = arrived + td["n_arrived"].sum(), lost + td["n_lost"].sum()
        assert torch.equal(env.station_dest, torch.tensor([[G, Y, B, R]]).repeat(n, 1))
        assert (td["reward"] == -4.0).all()
        assert (env.station_age == t + 1).all()
    assert arrived > 0 and lost == arrived


def run(env, actions):
    env.reset()
    return [env.step(a) for a in actions]


def test_population_equals_separate_runs():
    g = torch.Generator().manual_seed(0)
    actions = torch.randint(0, N_ACTIONS, (80, 12, 2), generator=g)
    big = run(TwoTaxiEnv([3, 5, 7], 4, mean_interarrival=4, max_episode_steps=30), actions)
    small = run(TwoTaxiEnv([5], 4, mean_interarrival=4, max_episode_steps=30), actions[:, 4:8])
    for a, b in zip(big, small, strict=True):
        assert (a[4:8] == b).all()


def test_state_dict_round_trip_continues_identically():
    g = torch.Generator().manual_seed(1)
    actions = torch.randint(0, N_ACTIONS, (60, 6, 2), generator=g)
    env = TwoTaxiEnv([0, 1], 3, mean_interarrival=4)
    env.reset()
    for a in actions[:30]:
        env.step(a)
    state = env.state_dict()
    first = [env.step(a) for a in actions[30:]]
    other = TwoTaxiEnv([0, 1], 3, mean_interarrival=4)
    other.load_state_dict(state)
    second = [other.step(a) for a in actions[30:]]
    for a, b in zip(first, second, strict=True):
        assert (a == b).all()


def test_observation_indices_and_metrics_are_consistent():
    n = 256
    env = TwoTaxiEnv([0], n, mean_interarrival=3)
    td = env.reset()
    assert (td["agents", "status"] == EMPTY).all() and (td["stations"] == 0).all()
    g = torch.Generator().manual_seed(4)
    delivered = []
    waited = []
    for _ in range(300):
        td = env.step(torch.randint(0, N_ACTIONS, (n, 2), generator=g))
        agents = td["agents"]
        codes = torch.stack([td[f"waiting_{k}"] for k in "RGYB"], 1)
        assert torch.equal((codes * 4 ** torch.arange(4)).sum(1), td["stations"])
        assert torch.equal((codes > 0).sum(1), td["n_waiting"])
        taxis = agents["taxi_loc"] * 5 + agents["status"]
        assert torch.equal(agents["own_state"], taxis * 256 + td["stations"][:, None])
        assert torch.equal(
            td["observation"], (taxis[:, 0] * 125 + taxis[:, 1]) * 256 + td["stations"]
        )
        assert (td["observation"] < env.observation_sizes["observation"]).all()
        assert torch.equal(agents["delivered"].sum(1), td["n_delivered"])
        assert (td["n_lost"] <= td["n_arrived"]).all()
        delivered.append(td["n_delivered"])
        waited.append(td["wait_delivered"])
    delivered, waited = torch.stack(delivered), torch.stack(waited)
    assert delivered.sum() > 0 and (waited >= delivered).all()  # every wait is >= 1 step
    per_window = throughput(delivered)
    assert per_window.shape == (n,)
    assert torch.allclose(per_window, delivered.sum(0).double() * 5000 / 300)
    total = average_wait(delivered.flatten()[:, None], waited.flatten()[:, None])
    assert total.item() >= 1.0


def test_bad_arguments_are_clear_errors():
    with pytest.raises(ValueError, match="mean_interarrival"):
        TwoTaxiEnv([0], 1, mean_interarrival=0.5)
    env = TwoTaxiEnv([0], 2)
    env.reset()
    with pytest.raises(ValueError, match=r"action 7 of agent 0 outside the action space"):
        env.step(torch.tensor([[7, 0], [0, 0]]))


def test_pettingzoo_and_torchrl_forms_pass_their_checkers():
    import warnings

    from pettingzoo.test import api_test, parallel_api_test
    from torchrl.envs.utils import check_env_specs

    from hrl_torch.env.pettingzoo_env import MultiAgentAECEnv, MultiAgentParallelEnv
    from hrl_torch.env.torchrl_multiagent import MultiAgentTorchRLEnv

    def make(seeds, envs):
        return TwoTaxiEnv(seeds, envs, mean_interarrival=3.0, max_episode_steps=60)

    with warnings.catch_warnings():  # Dict observations are the design here
        warnings.filterwarnings("ignore", "Observation is not a NumPy array")
        warnings.filterwarnings("ignore", "Observation space for each agent probably should")
        api_test(MultiAgentAECEnv(make, seed=3), num_cycles=150)
        parallel_api_test(MultiAgentParallelEnv(make, seed=3), num_cycles=150)
    check_env_specs(MultiAgentTorchRLEnv(make([0, 1], 3)))


@pytest.mark.parametrize("interarrival", [5, 20])
def test_per_station_arrivals_are_one_process_per_station(interarrival):
    n, steps = 2000, 60
    env = TwoTaxiEnv([0, 1], n // 2, mean_interarrival=interarrival, arrivals="station")
    env.reset()
    wait = torch.full((n, 2), WAIT)
    counts, arrived, several = torch.zeros(4), 0, 0
    for _ in range(steps):
        td = env.step(wait)
        counts += (env.station_dest != NO_PASSENGER).sum(0)  # each arrival, by station
        arrived += int(td["n_arrived"].sum())
        several += int((td["n_arrived"] > 1).sum())
        assert torch.equal(td["n_waiting"], td["n_arrived"])  # every station was free
        env.station_dest.fill_(NO_PASSENGER)  # keep every station free
    p = 1 / interarrival
    sd = (p * (1 - p) / (n * steps)) ** 0.5
    for s in range(4):  # each station its own rate 1 / interarrival, not a quarter of it
        assert abs(counts[s].item() / (n * steps) - p) < 4.5 * sd
    assert abs(arrived / (n * steps) - 4 * p) < 4.5 * 2 * sd
    assert several > 0  # up to four arrivals in one step; the grid process has at most one


def test_per_station_arrivals_at_occupied_stations_are_lost_one_by_one():
    n = 500
    env = TwoTaxiEnv([0], n, mean_interarrival=2, arrivals="station")
    env.reset()
    env.station_dest = torch.tensor([[G, Y, B, R]]).repeat(n, 1)
    wait = torch.full((n, 2), WAIT)
    for _ in range(10):
        td = env.step(wait)
        assert torch.equal(td["n_lost"], td["n_arrived"])
    assert torch.equal(env.station_dest, torch.tensor([[G, Y, B, R]]).repeat(n, 1))
    with pytest.raises(ValueError, match="arrivals"):
        TwoTaxiEnv([0], 1, arrivals="taxi")


def test_team_reward_is_the_same_for_both_taxis():
    env = TwoTaxiEnv([0], 1, mean_interarrival=NO_ARRIVALS)  # one reward per row: the team's
    env.reset()
    place(env, [23, 12], status=[Y, EMPTY], passengers={B: Y})
    td = step(env, PICKUP, NORTH)  # taxi 0 loaded at B: an illegal pickup; B's passenger waits
    assert td["agents", "reward"].tolist() == [[-11.0, -11.0]]
    place(env, [20, 12], status=[Y, EMPTY], passengers={B: Y, R: G})
    td = step(env, PUTDOWN, WAIT)  # taxi 0 delivers at Y; two passengers wait
    assert td["reward"].item() == 20.0 - 2.0
    assert td["agents", "reward"].tolist() == [[18.0, 18.0]]
    own = TwoTaxiEnv([0], 1, mean_interarrival=NO_ARRIVALS, own_rewards=True)  # the first build
    own.reset()
    place(own, [20, 12], status=[Y, EMPTY], passengers={B: Y, R: G})
    assert step(own, PUTDOWN, WAIT)["agents", "reward"].tolist() == [[19.0, -1.0]]
