import collections
import warnings

import gymnasium
import torch
from gymnasium.utils.env_checker import check_env
from torchrl.envs.utils import check_env_specs

import envs  # noqa: F401  (registers hrl/ ids)
from envs import agv_small as agv
from envs.agv_small import SmallAGVEnv, decode, encode, transition_tables
from hrl_torch.env.torchrl_env import TorchRLEnv

SOUTH, NORTH, EAST, WEST, LOAD, UNLOAD = range(6)
EMPTY, PART1, PART2 = range(3)


def at(row, col):
    return agv.CELLS.index((row, col))


def move(row, col, action):
    return agv.CELLS[int(agv.MOVE_TARGET[at(row, col), action])]


def distances(source, allowed=lambda loc: True):
    dist, queue = {source: 0}, collections.deque([source])
    while queue:
        loc = queue.popleft()
        for nxt in agv.MOVE_TARGET[loc].tolist():
            if nxt not in dist and allowed(nxt):
                dist[nxt] = dist[loc] + 1
                queue.append(nxt)
    return dist


def test_26_locations_times_3_statuses():
    assert (agv.N_LOCATIONS, agv.N_STATUS, agv.N_STATES) == (26, 3, 78)
    assert collections.Counter(agv.ROOM) == {agv.MACHINE_ROOM: 18, agv.DOOR: 2, agv.GOAL_ROOM: 6}
    named = {k: agv.CELLS[v] for k, v in agv.LABELS.items()}
    assert named == {
        "M1": (0, 4),
        "M2": (2, 4),
        "D1": (0, 6),
        "D2": (2, 6),
        "G1": (2, 7),
        "G2": (0, 7),
    }
    assert agv.ROOM[agv.M1] == agv.ROOM[agv.M2] == agv.MACHINE_ROOM
    assert agv.ROOM[agv.G1] == agv.ROOM[agv.G2] == agv.GOAL_ROOM


def test_walls_and_doors_by_hand():
    assert move(0, 5, EAST) == (0, 6) and move(0, 6, EAST) == (0, 7)  # through D1
    assert move(2, 5, EAST) == (2, 6) and move(2, 6, EAST) == (2, 7)  # through D2
    assert move(0, 6, SOUTH) == (0, 6) and move(2, 6, NORTH) == (2, 6)  # doors are corridors
    assert move(1, 5, EAST) == (1, 5) and move(1, 7, WEST) == (1, 7)  # wall between the rooms
    assert move(1, 3, SOUTH) == (1, 3) and move(2, 5, NORTH) == (2, 5)  # machine-room partition
    assert move(1, 0, SOUTH) == (2, 0)  # its opening
    assert move(0, 8, EAST) == (0, 8) and move(0, 0, NORTH) == (0, 0)  # outer walls
    assert move(2, 7, NORTH) == (1, 7) and move(1, 7, NORTH) == (0, 7)


def test_distances_behind_the_design():
    d_m1, d_g1 = distances(agv.M1), distances(agv.G1)
    assert d_m1[agv.G1] == 5 and d_g1[agv.M1] == 5  # through D1 both ways
    assert d_g1[at(2, 5)] == 2 and d_g1[at(0, 5)] == 4  # nearest way out of the goal room: D2
    assert distances(agv.G2)[at(0, 5)] == 2  # ... and from G2 it is D1
    in_machine_room = distances(at(2, 5), lambda loc: agv.ROOM[loc] == agv.MACHINE_ROOM)
    assert in_machine_room[agv.M1] == 11 and in_machine_room[agv.M2] == 1


def test_rewards_and_status_changes_by_hand():
    nxt, rew = transition_tables()
    delivered = agv.delivery_table()

    def step(loc, status, action):
        s = encode(loc, status)
        return int(nxt[s, action]), float(rew[s, action]), int(delivered[s, action])

    assert step(agv.M1, EMPTY, LOAD) == (encode(agv.M1, PART1), -1.0, 0)
    assert step(agv.M2, EMPTY, LOAD) == (encode(agv.M2, PART2), -1.0, 0)
    assert step(agv.M1, PART2, LOAD) == (encode(agv.M1, PART2), -1.0, 0)  # already loaded
    assert step(at(1, 1), EMPTY, LOAD) == (encode(at(1, 1), EMPTY), -1.0, 0)  # no machine
    assert step(agv.G1, PART1, UNLOAD) == (encode(agv.G1, EMPTY), 20.0, 1)
    assert step(agv.G2, PART2, UNLOAD) == (encode(agv.G2, EMPTY), 1.0, 2)
    assert step(agv.G2, PART1, UNLOAD) == (encode(agv.G2, PART1), -1.0, 0)  # wrong station
    assert step(agv.G1, EMPTY, UNLOAD) == (encode(agv.G1, EMPTY), -1.0, 0)
    assert step(at(0, 5), PART1, EAST) == (encode(agv.D1, PART1), -1.0, 0)
    assert (rew == 20).sum() == 1 and (rew == 1).sum() == 1 and (rew == -1).sum() == 78 * 6 - 2
    # moves never change the status
    assert (nxt[:, :4] % 3 == torch.arange(78)[:, None] % 3).all()


def test_decode_fields():
    f = decode(torch.tensor([encode(agv.G1, PART2)]))
    assert (int(f["location"]), int(f["status"]), int(f["row"]), int(f["col"])) == (agv.G1, 2, 2, 7)
    assert int(f["room"]) == agv.GOAL_ROOM and int(f["observation"]) == encode(agv.G1, PART2)


def test_batched_env_equals_the_tables_and_never_ends():
    nxt, rew = transition_tables()
    delivered = agv.delivery_table()
    env = SmallAGVEnv([0, 1], 8)
    state = env.reset()["observation"]
    gen = torch.Generator().manual_seed(0)
    for _ in range(300):
        action = torch.randint(0, 6, (16,), generator=gen)
        td = env.step(action)
        assert torch.equal(td["observation"], nxt[state, action])
        assert torch.equal(td["reward"], rew[state, action])
        assert torch.equal(td["delivered"], delivered[state, action])
        assert not (td["terminated"] | td["truncated"] | td["is_init"]).any()
        assert (td["duration"] == 1).all()
        state = td["observation"]


def test_starts_empty_anywhere_in_the_machine_room():
    obs = SmallAGVEnv([0], 2000).reset()
    assert (obs["status"] == EMPTY).all() and (obs["room"] == agv.MACHINE_ROOM).all()
    assert set(obs["location"].tolist()) == set(agv.MACHINE_ROOM_LOCATIONS.tolist())


def test_throughput_weights_part1_by_20_per_10000_steps():
    delivered = torch.zeros(100, 3, dtype=torch.long)
    delivered[[3, 50], 0] = 1
    delivered[[1, 2, 3], 1] = 2
    assert agv.throughput(delivered).tolist() == [4000.0, 300.0, 0.0]
    assert agv.delivery_weight_table()[encode(agv.G1, PART1), UNLOAD] == 20


def test_checkers_pass():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(gymnasium.make("hrl/SmallAGV-v0").unwrapped, skip_render_check=True)
    env = gymnasium.make("hrl/SmallAGV-v0")  # continuing: no time limit, never terminates
    assert env.spec.max_episode_steps is None
    obs, _ = env.reset(seed=3)
    for t in range(200):
        obs, reward, terminated, truncated, _ = env.step(t % 6)
        assert obs in env.observation_space and not (terminated or truncated)
    check_env_specs(TorchRLEnv(SmallAGVEnv([0, 1], 3)))
