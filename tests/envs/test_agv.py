import gymnasium
import pytest
import torch

import envs  # noqa: F401  (registers the hrl/ ids)
from agents.agv import dispatch_action
from envs.agv import (
    BAYS,
    DROP_OFF,
    EMPTY,
    FORWARD,
    IDLE,
    LOAD,
    LOC,
    N_ACTIONS,
    N_LOCATIONS,
    N_STATES,
    PICK_UP,
    TURN,
    UNLOAD,
    AGVEnv,
    AGVRewards,
    decode,
    encode,
    shortest_paths,
    successors,
)

FAR = 1e6  # a timer that will not fire during a test


def random_states(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    return dict(
        location=torch.randint(0, 33, (n,), generator=g),
        status=torch.randint(0, 7, (n,), generator=g),
        drop_off=torch.randint(0, 3, (n, 3), generator=g),
        pick_up=torch.randint(0, 3, (n, 3), generator=g),
        warehouse=torch.randint(0, 2, (n, 3), generator=g),
    )


def quiet_env(b=1, **kwargs):
    """An env whose arrival timer never fires (no parts appear in the warehouse)."""
    env = AGVEnv([0], b, **kwargs)
    env.reset()
    env.to_arrival.fill_(FAR)
    return env


def put(env, **state):
    for k, v in state.items():
        getattr(env, k)[:] = torch.as_tensor(v)


def step(env, action):
    return env.step(torch.full((env.batch_size,), action, dtype=torch.long))


# ---------------------------------------------------------------- state space and layout
def test_flat_state_count():
    assert N_STATES == 33 * 3**6 * 7 * 2**3 == 1_347_192
    assert N_LOCATIONS == 33 and N_ACTIONS == 5


def test_encode_decode_round_trip():
    s = random_states(20_000)
    index = encode(**s)
    assert int(index.min()) >= 0 and int(index.max()) < N_STATES
    fields = decode(index)
    assert torch.equal(fields["location"], s["location"])
    assert torch.equal(fields["status"], s["status"])
    for i in range(3):
        assert torch.equal(fields[f"drop_off_{i + 1}"], s["drop_off"][:, i])
        assert torch.equal(fields[f"pick_up_{i + 1}"], s["pick_up"][:, i])
        assert torch.equal(fields[f"warehouse_{i + 1}"], s["warehouse"][:, i])
    idx = torch.randint(0, N_STATES, (20_000,), generator=torch.Generator().manual_seed(1))
    f = decode(idx)
    again = encode(
        f["location"],
        f["status"],
        *(
            torch.stack([f[f"{k}_{i}"] for i in (1, 2, 3)], -1)
            for k in ("drop_off", "pick_up", "warehouse")
        ),
    )
    assert torch.equal(again, idx)
    assert int(encode(**{k: v[:1] * 0 for k, v in s.items()})) == 0
    top = encode(
        torch.tensor([32]),
        torch.tensor([6]),
        torch.full((1, 3), 2),
        torch.full((1, 3), 2),
        torch.ones(1, 3, dtype=torch.long),
    )
    assert int(top) == N_STATES - 1


def test_layout_is_a_strongly_connected_one_way_network():
    succ = successors()
    assert succ.shape == (33, 2)
    junctions = {k for k in range(33) if succ[k, 1] != k}
    assert junctions == {LOC["J1"], LOC["J2"], LOC["J3"], LOC["JW"]}
    dist, first = shortest_paths()
    assert bool((dist[~torch.eye(33, dtype=torch.bool)] > 0).all())  # every pair reachable
    assert int(dist[LOC["W1"], LOC["D1"]]) == 7 and int(dist[LOC["P1"], LOC["WA"]]) == 4
    assert int(dist[LOC["D1"], LOC["P1"]]) == 1
    assert int(dist[LOC["P1"], LOC["D1"]]) == 10  # via the bypass
    # following first moves reaches the target in exactly `dist` moves
    here = torch.arange(33).repeat_interleave(33)
    target = torch.arange(33).repeat(33)
    for _ in range(int(dist.max())):
        here = torch.where(here == target, here, succ[here, first[here, target]])
    assert torch.equal(here, target)


# ---------------------------------------------------------------- hand-checked transitions
@pytest.mark.parametrize(
    ("start", "action", "end"),
    [
        ("J1", TURN, "D1"),
        ("J1", FORWARD, "3"),
        ("J3", TURN, "D3"),
        ("J3", FORWARD, "TR"),
        ("JW", TURN, "WA"),
        ("JW", FORWARD, "19"),
        ("D2", FORWARD, "P2"),
        ("P2", FORWARD, "K2"),
        ("WX", FORWARD, "TL"),
        ("21", FORWARD, "TL"),
        ("BR", FORWARD, "K3"),
        ("TL", TURN, "TL"),
        ("D1", TURN, "D1"),
        ("J2", LOAD, "J2"),
        ("J2", UNLOAD, "J2"),
        ("J2", IDLE, "J2"),
    ],
)
def test_moves_follow_the_network(start, action, end):
    env = quiet_env()
    put(env, location=LOC[start])
    td = step(env, action)
    assert int(td["location"]) == LOC[end]


def test_moves_match_the_successor_table_everywhere():
    env = quiet_env(66)
    loc = torch.arange(33).repeat(2)
    action = torch.arange(2).repeat_interleave(33)
    env.location = loc.clone()
    td = env.step(action)
    assert torch.equal(td["location"], successors()[loc, action])


def test_load_and_unload_rules():
    env = AGVEnv([0], 1, rewards=AGVRewards(assembly=3.0, part=0.5, rate=0.0))
    env.reset()
    env.to_arrival.fill_(FAR)
    # a part: load at its bay, wrong unloads do nothing, unload at its drop-off
    put(env, location=LOC["W2"], warehouse=torch.tensor([[1, 1, 0]]))
    td = step(env, LOAD)
    assert int(td["status"]) == 2 and int(td["warehouse_2"]) == 0 and int(td["warehouse_1"]) == 1
    td = step(env, LOAD)  # already carrying: nothing
    assert int(td["status"]) == 2 and int(td["warehouse_1"]) == 1
    put(env, location=LOC["D1"])
    td = step(env, UNLOAD)
    assert int(td["status"]) == 2 and int(td["drop_off_1"]) == 0 and int(td["delivery"]) == 0
    put(env, location=LOC["D2"])
    td = step(env, UNLOAD)
    assert int(td["status"]) == 0 and int(td["drop_off_2"]) == 1
    assert int(td["delivery"]) == 2 and float(td["reward"]) == 0.5
    # loading where nothing waits does nothing
    put(env, location=LOC["W3"])
    assert int(step(env, LOAD)["status"]) == 0
    # an assembly: load at its pick-up, unload only at WA
    put(env, location=LOC["P3"], pick_up=torch.tensor([[0, 0, 2]]))
    td = step(env, LOAD)
    assert int(td["status"]) == 6 and int(td["pick_up_3"]) == 1
    put(env, location=LOC["W3"])
    td = step(env, UNLOAD)
    assert int(td["status"]) == 6 and float(td["assemblies_delivered"]) == 0
    put(env, location=LOC["WA"])
    td = step(env, UNLOAD)
    assert int(td["status"]) == 0 and int(td["delivery"]) == 6
    assert float(td["assemblies_delivered"]) == 1 and float(td["reward"]) == 3.0
    td = step(env, IDLE)
    assert int(td["delivery"]) == 0 and float(td["assemblies_delivered"]) == 0


def test_drop_off_buffer_limit_and_returning_a_part():
    env = quiet_env()
    put(
        env,
        location=LOC["D1"],
        status=1,
        drop_off=torch.tensor([[2, 0, 0]]),
        pick_up=torch.tensor([[2, 0, 0]]),
    )
    td = step(env, UNLOAD)  # D1 full: the part stays on the AGV
    assert int(td["status"]) == 1 and int(td["drop_off_1"]) == 2
    assert not bool(env.busy[0, 0])  # M1 is blocked: P1 is full
    put(env, location=LOC["W1"])
    td = step(env, UNLOAD)  # back into its empty bay
    assert int(td["status"]) == 0 and int(td["warehouse_1"]) == 1 and int(td["delivery"]) == 0
    put(env, status=1)
    td = step(env, UNLOAD)  # bay already holds one: the returned part is lost
    assert int(td["status"]) == 0 and int(td["warehouse_1"]) == 1
    assert float(td["parts_lost"]) == 1


def test_blocked_machine_restarts_when_its_output_is_emptied():
    env = quiet_env()
    put(
        env,
        location=LOC["P1"],
        drop_off=torch.tensor([[1, 0, 0]]),
        pick_up=torch.tensor([[2, 0, 0]]),
    )
    step(env, IDLE)
    assert not bool(env.busy[0, 0])
    td = step(env, LOAD)
    assert int(td["pick_up_1"]) == 1 and bool(env.busy[0, 0])


@pytest.mark.parametrize("continuous", [False, True])
def test_assembly_completes_after_its_time(continuous):
    b = 300
    env = quiet_env(b, continuous=continuous)
    rows, station = torch.arange(b), torch.arange(b) % 3
    put(env, location=torch.tensor(DROP_OFF)[station], status=1 + station)
    td = env.step(torch.full((b,), UNLOAD))
    assert bool((td["delivery"] == 1 + station).all())
    assert bool(env.busy[rows, station].all())
    # the machine started at the unload's decision epoch: assembly time = remaining + tau_0
    remaining = env.to_finish[rows, station].clone()
    assembly = remaining + td["duration"]
    since = torch.zeros(b)  # time since the end of the unload step
    seen = torch.zeros(b, dtype=torch.bool)
    for _ in range(40):
        td = env.step(torch.full((b,), IDLE))
        before, since = since, since + td["duration"]
        pick = torch.stack([td[f"pick_up_{i}"] for i in (1, 2, 3)], -1)[rows, station]
        drop = torch.stack([td[f"drop_off_{i}"] for i in (1, 2, 3)], -1)[rows, station]
        now = (pick == 1) & ~seen
        # completes in the first step whose end reaches the assembly time, not earlier
        assert bool((before[now] < remaining[now] + 1e-3).all())
        assert bool((since[now] >= remaining[now] - 1e-3).all())
        assert bool((drop[now] == 0).all())
        assert bool((pick[~seen & ~now] == 0).all())
        seen |= now
    assert bool(seen.all())
    mean = (100.0, 120.0, 180.0) if continuous else (6.0, 10.0, 12.0)
    for i in range(3):
        a = assembly[station == i]
        assert abs(float(a.mean()) - float(mean[i])) < (2.0 if continuous else 0.6)
        if not continuous:  # integer steps, mean -+ 4
            assert bool((a == a.round()).all())
            assert float(a.min()) >= mean[i] - 4 and float(a.max()) <= mean[i] + 4


# ---------------------------------------------------------------- stochastic processes
@pytest.mark.parametrize(("continuous", "mean"), [(False, 12.0), (True, 100.0)])
def test_arrivals_follow_the_mix_and_rate(continuous, mean):
    b, steps = 512, 400
    env = AGVEnv([7], b, continuous=continuous)
    env.reset()
    counts, time = torch.zeros(3), 0.0
    for _ in range(steps):
        env.warehouse.zero_()  # empty bays: every arrival shows up
        td = step(env, IDLE)
        counts += torch.stack([td[f"warehouse_{i}"] for i in (1, 2, 3)], -1).sum(0).float()
        time += float(td["duration"].sum())
    assert float(td["parts_lost"].sum()) == 0
    frac = counts / counts.sum()
    assert torch.allclose(frac, torch.tensor([0.40, 0.35, 0.25]), atol=0.015), frac
    assert abs(time / float(counts.sum()) - mean) < 0.03 * mean


def test_arrivals_at_a_full_bay_are_lost():
    env = AGVEnv([3], 256)
    env.reset()
    env.warehouse.fill_(1)
    lost = 0.0
    for _ in range(120):
        td = step(env, IDLE)
        lost += float(td["parts_lost"].sum())
    assert bool((env.warehouse == 1).all())
    assert 256 * 9 <= lost <= 256 * 10  # every arrival: 120 steps / 12 (the first at 10-14)


def moments(x):
    return float(x.mean()), float(x.var())


def test_discrete_time_distributions_match_table_4_1():
    env = AGVEnv([0], 4096)
    gaps = torch.cat([env._draw_gap() for _ in range(50)])
    assert set(gaps.unique().tolist()) == {10.0, 11.0, 12.0, 13.0, 14.0}
    m, v = moments(gaps)
    assert abs(m - 12) < 0.03 and abs(v - 2) < 0.05
    asm = torch.cat([env._draw_assembly() for _ in range(50)])
    for i, mean in enumerate((6.0, 10.0, 12.0)):
        m, v = moments(asm[:, i])
        assert abs(m - mean) < 0.03 and abs(v - 2) < 0.05
        assert bool((asm[:, i] == asm[:, i].round()).all()) and float(asm[:, i].min()) >= 1
    assert bool((step(env, FORWARD)["duration"] == 1).all())


def test_continuous_time_distributions_match_table_4_2():
    env = AGVEnv([0], 4096, continuous=True)
    env.reset()
    tau = torch.cat([step(env, IDLE)["duration"] for _ in range(50)])
    m, v = moments(tau)
    assert abs(m - 10) < 0.02 and abs(v - 2) < 0.05 and float(tau.min()) > 0
    gaps = torch.cat([env._draw_gap() for _ in range(50)])
    m, v = moments(gaps)
    assert abs(m - 100) < 0.05 and abs(v - 20) < 0.4
    half = (3 * 20) ** 0.5
    assert float(gaps.min()) >= 100 - half - 1e-3 and float(gaps.max()) <= 100 + half + 1e-3
    asm = torch.cat([env._draw_assembly() for _ in range(50)])
    for i, mean in enumerate((100.0, 120.0, 180.0)):
        m, v = moments(asm[:, i])
        assert abs(m - mean) < 0.05 and abs(v - 20) < 0.4


@pytest.mark.parametrize("continuous", [False, True])
def test_reward_is_lump_plus_rate_times_duration(continuous):
    rewards = AGVRewards(assembly=5.0, part=0.25, rate=-0.1)
    env = AGVEnv([1, 2], 32, continuous=continuous, rewards=rewards)
    td = env.reset()
    n_asm = n_part = 0.0
    for _ in range(600):
        td = env.step(dispatch_action(td))
        part = ((td["delivery"] >= 1) & (td["delivery"] <= 3)).float()
        asm = td["assemblies_delivered"]
        assert bool((asm == (td["delivery"] >= 4).float()).all())
        expected = 5.0 * asm + 0.25 * part - 0.1 * td["duration"]
        assert torch.allclose(td["reward"], expected, atol=1e-5)
        if continuous:
            assert bool((td["duration"] > 0).all()) and float(td["duration"].std()) > 0
        else:
            assert bool((td["duration"] == 1).all())
        n_asm += float(asm.sum())
        n_part += float(part.sum())
    assert n_asm > 0 and n_part > 0


@pytest.mark.parametrize(("continuous", "low"), [(False, 0.02), (True, 0.002)])
def test_dispatching_rule_delivers_assemblies(continuous, low):
    env = AGVEnv([0], 64, continuous=continuous)
    td = env.reset()
    delivered = elapsed = 0.0
    for _ in range(800):
        td = env.step(dispatch_action(td))
        assert not bool(td["terminated"].any() | td["truncated"].any())
        delivered += float(td["assemblies_delivered"].sum())
        elapsed += float(td["duration"].sum())
    assert delivered / elapsed > low  # throughput per step / per second


def items_in_the_system(td):
    """``[B]`` parts and assemblies inside the factory: bays, buffers, machines and the AGV."""
    fields = ("warehouse", "drop_off", "pick_up")  # drop_off counts the part on the machine
    held = sum(td[f"{name}_{i}"] for name in fields for i in (1, 2, 3))
    return held + (td["status"] != EMPTY).long()


def test_random_policy_conserves_parts_and_delivers():
    # conservation, in every row after every step: parts that arrived = parts and assemblies
    # in the system + assemblies delivered + parts lost (arrivals at a full bay and parts
    # returned to a full bay). Arrivals are read from the hidden timer: inter-arrival times
    # (10-14 steps) exceed the step (1), so a step has an arrival iff the timer was refilled
    b, steps = 128, 1000
    env = AGVEnv([0], b)
    env.reset()
    arrived, delivered, lost = torch.zeros(b), torch.zeros(b), torch.zeros(b)
    dropped = torch.zeros(b)
    for _ in range(steps):
        timer = env.to_arrival.clone()
        td = env.step(env.rng.integers(N_ACTIONS))
        arrived += (env.to_arrival > timer - td["duration"] + 1e-3).float()
        delivered += td["assemblies_delivered"]
        lost += td["parts_lost"]
        dropped += ((td["delivery"] >= 1) & (td["delivery"] <= 3)).float()
        assert torch.equal(arrived, items_in_the_system(td) + delivered + lost)
    # first arrival after 10-14 steps, then one every 10-14: 71 to 100 arrivals per row
    assert int(arrived.min()) >= (steps - 14) // 14 + 1 and int(arrived.max()) <= steps // 10
    assert abs(float(arrived.mean()) - steps / 12) < 2
    # every flow of the identity is exercised: the random policy delivers some parts and
    # assemblies (seeded: 142 parts dropped, 63 assemblies), and loses most arrivals
    assert float(dropped.sum()) > 0 and float(delivered.sum()) > 0
    assert float(lost.sum()) > 0.9 * float(arrived.sum())


@pytest.mark.parametrize("continuous", [False, True])
def test_dispatching_rule_delivers_exactly_the_parts_it_is_given(continuous):
    # no arrivals; one part of each type waits in its bay: the dispatching rule must deliver
    # exactly three assemblies per row (measured: all rows by step 112 in discrete time, 110
    # in continuous time), lose nothing and end idle at WA with every buffer empty
    b = 64
    env = quiet_env(b, continuous=continuous)
    env.warehouse[:] = 1
    td = env.step(torch.full((b,), IDLE))  # observe the planted parts
    delivered = torch.zeros(b)
    for _ in range(200):
        td = env.step(dispatch_action(td))
        delivered += td["assemblies_delivered"]
        assert float(td["parts_lost"].sum()) == 0
        assert torch.equal(items_in_the_system(td) + delivered, torch.full((b,), 3.0))
    assert torch.equal(delivered, torch.full((b,), 3.0))
    assert int(items_in_the_system(td).sum()) == 0
    assert bool((td["location"] == LOC["WA"]).all())


# ---------------------------------------------------------------- batching and APIs
def rollout(env, steps=300):
    td = env.reset()
    out = []
    for _ in range(steps):
        td = env.step(dispatch_action(td))
        out.append(torch.stack([td["observation"].float(), td["reward"], td["duration"]], -1))
    return torch.stack(out, 1)


@pytest.mark.parametrize("continuous", [False, True])
def test_a_learner_sees_the_same_env_alone_or_in_a_population(continuous):
    alone = rollout(AGVEnv([5], 4, continuous=continuous))
    population = rollout(AGVEnv([2, 5, 9], 4, continuous=continuous))
    assert torch.equal(alone, population[4:8])
    assert not torch.equal(population[:4], population[4:8])


def test_state_dict_resumes_exactly():
    env = AGVEnv([4], 8, continuous=True)
    td = env.reset()
    for _ in range(50):
        td = env.step(dispatch_action(td))
    state = env.state_dict()

    def run(e, td):
        out = []
        for _ in range(30):
            td = e.step(dispatch_action(td))
            out.append(torch.stack([td["observation"].float(), td["duration"]], -1))
        return torch.stack(out)

    first = run(env, td)
    other = AGVEnv([4], 8, continuous=True)
    other.load_state_dict(state)
    assert torch.equal(run(other, td), first)


@pytest.mark.parametrize("env_id", ["hrl/AGV-v0", "hrl/AGVContinuous-v0"])
def test_gymnasium_check_env(env_id):
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make(env_id)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    assert obs["location"] == LOC["WA"] and 0 <= obs["observation"] < N_STATES
    total = 0.0
    for _ in range(50):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert not terminated and not truncated and info["duration"] > 0
        total += info["duration"]
    assert total == pytest.approx(50.0 if env_id == "hrl/AGV-v0" else 500.0, rel=0.1)


@pytest.mark.parametrize("continuous", [False, True])
def test_torchrl_check_env_specs(continuous):
    from torchrl.envs.utils import check_env_specs

    from hrl_torch.env.torchrl_env import TorchRLEnv

    env = TorchRLEnv(AGVEnv([0, 1], 3, continuous=continuous))
    check_env_specs(env)
    td = env.rollout(20)
    assert td.shape == (6, 20)
    assert not bool(td["next", "done"].any())


def test_station_tables():
    assert [LOC[f"D{i}"] for i in (1, 2, 3)] == list(DROP_OFF)
    assert [LOC[f"P{i}"] for i in (1, 2, 3)] == list(PICK_UP)
    assert [LOC[f"W{i}"] for i in (1, 2, 3)] == list(BAYS)
