import copy

import pytest
import torch

from agents.four_agv_rules import FirstComeFirstServe
from envs.four_agv import (
    BAYS,
    DROP_OFF,
    EMPTY,
    FIGURE_6_5,
    FORWARD,
    IDLE,
    LEFT,
    LOAD,
    LOC,
    N_ACTIONS,
    N_LOCATIONS,
    PICK_UP,
    RIGHT,
    TABLE_6_1,
    UNLOAD,
    WAREHOUSE_DROP,
    AGVRewards,
    FourAGVEnv,
    FourAGVTiming,
    decode,
    encode,
    n_flat_states,
    shortest_paths,
    successors,
)
from hrl_torch.common.rng import BatchRNG

FAR = 1e6  # a timer that will not fire during a test


def quiet_env(b=1, n_agents=4, **kwargs):
    """A reset env whose arrival timer never fires (no parts appear in the warehouse)."""
    env = FourAGVEnv([0], b, n_agents=n_agents, **kwargs)
    td = env.reset()
    env.to_arrival.fill_(FAR)
    return env, td


def put(env, **state):
    for k, v in state.items():
        getattr(env, k)[:] = torch.as_tensor(v)


def act(env, *actions):
    """Step with one action per agent (the same in every row)."""
    a = torch.tensor(actions).expand(env.batch_size, env.n_agents)
    return env.step(a)


def buffers(td, name):
    return torch.stack([td[f"{name}_{i}"] for i in (1, 2, 3, 4)], -1)


# ---------------------------------------------------------------- layout and state space
def test_layout_has_100_locations_and_is_a_strongly_connected_one_way_network():
    succ = successors()
    assert succ.shape == (N_LOCATIONS, 3) and N_LOCATIONS == 100 and N_ACTIONS == 6
    branching = {k for k in range(100) if bool((succ[k, 1:] != k).any())}
    assert branching == {LOC["J1"], LOC["J2"], LOC["JE"]}
    assert succ[LOC["J1"]].tolist() == [9, LOC["D1"] - 1, LOC["D3"] - 1]  # Forward, Left, Right
    assert int(succ[LOC["JE"], FORWARD]) == LOC["JE"]  # the T junction has no straight on
    for i in range(4):  # each branch passes Di, the machine, then Pi
        assert int(succ[succ[DROP_OFF[i], 0], 0]) == PICK_UP[i]
    entered = {int(s) for k in range(100) for s in succ[k] if int(s) != k}
    assert entered == set(range(100))  # every location has a predecessor
    dist, first = shortest_paths()
    assert bool((dist[~torch.eye(100, dtype=torch.bool)] > 0).all())
    assert int(dist[WAREHOUSE_DROP, LOC["D1"]]) == 10 and int(dist[LOC["P1"], WAREHOUSE_DROP]) == 16
    assert int(dist[LOC["P3"], WAREHOUSE_DROP]) == 16 and int(dist[LOC["D2"], LOC["P2"]]) == 2
    assert int(dist[LOC["P1"], LOC["D1"]]) == 26  # round the north loop
    # following first moves reaches the target in exactly `dist` moves
    here = torch.arange(100).repeat_interleave(100)
    target = torch.arange(100).repeat(100)
    steps = torch.zeros_like(here)
    for _ in range(int(dist.max())):
        moving = here != target
        steps += moving.long()
        here = torch.where(moving, succ[here, first[here, target]], here)
    assert torch.equal(here, target) and torch.equal(steps, dist.flatten())


def test_flat_state_count_and_encoding():
    assert n_flat_states() == 100 * 4**8 * 9 * 2**4 == 943_718_400  # the text's ~10^9
    assert n_flat_states(1) == 100 * 2**8 * 9 * 2**4
    g = torch.Generator().manual_seed(0)
    index = torch.randint(0, n_flat_states(), (20_000,), generator=g)
    f = decode(index)
    again = encode(
        f["location"],
        f["status"],
        buffers(f, "drop_off"),
        buffers(f, "pick_up"),
        buffers(f, "warehouse"),
    )
    assert torch.equal(again, index)
    assert int(f["location"].max()) == 99 and int(f["status"].max()) == 8


def test_observation_fields_and_sizes():
    env, td = quiet_env(3, capacity=2)
    assert td.batch_size == (3,) and td["agents"].batch_size == (3, 4)
    assert bool(td["agents", "acting"].all()) and bool(td["is_init"].all())
    assert bool((td["agents", "location"] == WAREHOUSE_DROP).all())
    assert td["pick_up_age"].shape == (3, 4, 2) and td["bay_age"].shape == (3, 4)
    assert env.observation_sizes["drop_off_1"] == 3 and env.observation_sizes["warehouse_4"] == 2
    assert env.agent_observation_sizes == {
        "location": 100,
        "status": 9,
        "delivery": 9,
        "observation": n_flat_states(2),
    }
    rows = env.agent_rows(td)
    assert rows.batch_size == (12,) and rows["agent"].tolist() == [0, 1, 2, 3] * 3
    assert rows["pick_up_age"].shape == (12, 4, 2)


# ---------------------------------------------------------------- hand-checked dynamics
def test_an_agent_loads_at_a_bay_drives_and_unloads_at_its_drop_off():
    env, _ = quiet_env(n_agents=2, rewards=AGVRewards(part=0.5))
    put(env, warehouse=[[0, 1, 0, 0]], location=[[BAYS[1], WAREHOUSE_DROP]])
    td = act(env, LOAD, IDLE)
    agents = td["agents"]
    assert agents["status"].tolist() == [[2, 0]] and int(td["warehouse_2"]) == 0
    assert agents["acting"].tolist() == [[True, False]]  # 1 ms load, 1 s idle
    idle_left = float(env.to_end[0, 1])
    elapsed = float(td["duration"])
    dist, first = shortest_paths()
    here = BAYS[1]
    for _ in range(int(dist[here, DROP_OFF[1]])):
        move = int(first[here, DROP_OFF[1]])
        td = act(env, move, FORWARD)  # agent 1's action is ignored: it is still idling
        here = int(successors()[here, move])
        assert td["agents", "location"].tolist() == [[here, WAREHOUSE_DROP]]
        assert td["agents", "acting"].tolist() == [[True, False]]
        elapsed += float(td["duration"])
    assert here == DROP_OFF[1] and elapsed < idle_left
    td = act(env, UNLOAD, FORWARD)
    assert td["agents", "status"].tolist() == [[0, 0]] and int(td["drop_off_2"]) == 1
    assert td["agents", "delivery"].tolist() == [[2, 0]]
    assert float(td["parts_delivered"]) == 1 and float(td["reward"]) == 0.5
    assert bool(env.busy[0, 1]) and not bool(env.busy[0, [0, 2, 3]].any())  # M2 started
    td = act(env, IDLE, FORWARD)
    assert td["agents", "delivery"].tolist() == [[0, 0]] and float(td["reward"]) == 0


def test_load_and_unload_rules():
    env, _ = quiet_env(n_agents=1, rewards=AGVRewards(assembly=3.0))
    put(env, location=LOC["D1"], status=2)
    td = act(env, UNLOAD)  # part 2 does not go into D1
    assert int(td["agents", "status"]) == 2 and int(td["drop_off_1"]) == 0
    put(env, location=BAYS[1])
    td = act(env, UNLOAD)  # back into its empty bay
    assert int(td["agents", "status"]) == 0 and int(td["warehouse_2"]) == 1
    assert int(td["agents", "delivery"]) == 0 and float(td["parts_lost"]) == 0
    put(env, status=2)
    td = act(env, UNLOAD)  # the bay holds one part: the returned one is lost
    assert int(td["warehouse_2"]) == 1 and float(td["parts_lost"]) == 1
    td = act(env, LOAD)
    assert int(td["agents", "status"]) == 2 and int(td["warehouse_2"]) == 0
    td = act(env, LOAD)  # already loaded
    assert int(td["agents", "status"]) == 2
    put(env, status=0, location=PICK_UP[3], pick_up=[[0, 0, 0, 2]])
    td = act(env, LOAD)
    assert int(td["agents", "status"]) == 8 and int(td["pick_up_4"]) == 1
    put(env, location=BAYS[3])
    assert int(act(env, UNLOAD)["agents", "status"]) == 8  # assemblies only unload at WA
    put(env, location=WAREHOUSE_DROP)
    td = act(env, UNLOAD)
    assert int(td["agents", "status"]) == 0 and int(td["agents", "delivery"]) == 8
    assert float(td["assemblies_delivered"]) == 1 and float(td["reward"]) == 3.0
    put(env, location=LOC["W1"])
    assert int(act(env, LOAD)["agents", "status"]) == 0  # nothing waits
    for move, start in ((LEFT, "W1"), (RIGHT, "12"), (FORWARD, "JE")):  # no branch: stay
        put(env, location=LOC[start])
        assert int(act(env, move)["agents", "location"]) == LOC[start]


def test_simultaneous_agents_are_served_loads_first_then_unloads_in_agent_order():
    env, _ = quiet_env(n_agents=4)
    # three agents load at W1 (one part), the last returns part 1 there at the same epoch
    put(env, location=BAYS[0], warehouse=[[1, 0, 0, 0]], status=[[0, 0, 0, 1]])
    td = act(env, LOAD, LOAD, IDLE, UNLOAD)
    assert td["agents", "status"].tolist() == [[1, 0, 0, 0]]
    assert int(td["warehouse_1"]) == 1 and float(td["parts_lost"]) == 0
    # four agents unload part 1 at D1 with room for two; then two return to a full bay
    env, _ = quiet_env(n_agents=4)
    put(env, location=DROP_OFF[0], status=1, drop_off=[[1, 0, 0, 0]], pick_up=[[3, 0, 0, 0]])
    td = act(env, UNLOAD, UNLOAD, UNLOAD, UNLOAD)
    assert td["agents", "status"].tolist() == [[0, 0, 1, 1]] and int(td["drop_off_1"]) == 3
    assert td["agents", "delivery"].tolist() == [[1, 1, 0, 0]]
    assert float(td["parts_delivered"]) == 2 and not bool(env.busy[0, 0])  # P1 full: blocked
    put(env, location=BAYS[0], warehouse=[[0, 0, 0, 0]])
    env.to_end.zero_()
    env.acting.fill_(True)
    td = act(env, IDLE, IDLE, UNLOAD, UNLOAD)
    assert td["agents", "status"].tolist() == [[0, 0, 0, 0]] and int(td["warehouse_1"]) == 1
    assert float(td["parts_lost"]) == 1


def test_machine_assembles_blocks_and_restarts_when_its_output_is_emptied():
    cap = 3
    env, _ = quiet_env(n_agents=1)
    put(env, location=PICK_UP[0], drop_off=[[2, 0, 0, 0]], pick_up=[[cap, 0, 0, 0]])
    env.pick_up_age[0, 0] = torch.tensor([30.0, 20.0, 10.0], dtype=torch.float64)
    td = act(env, IDLE)
    assert not bool(env.busy[0, 0])  # blocked: P1 full
    d = float(td["duration"])
    assert torch.allclose(td["pick_up_age"][0, 0], torch.tensor([30.0, 20.0, 10.0]) + d)
    td = act(env, LOAD)  # takes the oldest assembly; M1 restarts at this epoch
    assert int(td["pick_up_1"]) == 2 and int(td["agents", "status"]) == 5
    assert bool(env.busy[0, 0])
    assert td["pick_up_age"][0, 0, 2] == 0 and td["pick_up_age"][0, 0, 0] > 20
    remaining = float(env.to_finish[0, 0])  # assembly time left after the load step
    assembly = remaining + float(td["duration"])
    assert 15 - 6 * 2**0.5 <= assembly <= 15 + 6 * 2**0.5
    since = 0.0
    while int(td["pick_up_1"]) == 2:
        before = since
        td = act(env, IDLE)
        since += float(td["duration"])
    # completes in the first step whose end reaches the assembly time; blocked again
    assert before < remaining <= since
    assert int(td["pick_up_1"]) == 3 and int(td["drop_off_1"]) == 1
    assert not bool(env.busy[0, 0])
    # the new assembly's age is the time since it completed
    assert float(td["pick_up_age"][0, 0, 2]) == pytest.approx(since - remaining, abs=1e-4)


def test_the_clock_advances_to_the_earliest_ending_action_and_only_those_agents_act():
    env, _ = quiet_env(b=64, n_agents=4)
    td = act(env, IDLE, FORWARD, IDLE, LOAD)  # everyone starts at the reset
    tau = env.to_end + td["duration"][:, None].double()  # the four drawn durations
    acting = td["agents", "acting"]
    assert torch.allclose(td["duration"].double(), tau.min(1).values)
    assert torch.equal(acting, env.to_end == 0) and not bool(acting[:, [0, 2]].any())
    assert bool((acting.sum(1) == 1).all())  # forward or load, never both (continuous times)
    # the next step starts only the acting agent's new action; the others' keep running
    before = env.location.clone()
    td = act(env, FORWARD, FORWARD, FORWARD, FORWARD)
    assert torch.equal(td["agents", "location"] != before, acting)


@pytest.mark.parametrize("n_agents", [1, 4])
def test_agent_reward_and_duration_are_the_sums_over_its_action(n_agents):
    rewards = AGVRewards(assembly=1.0, part=0.5, rate=-0.01)
    env = FourAGVEnv([3, 4], 8, n_agents=n_agents, rewards=rewards, timing=FIGURE_6_5)
    rule = FirstComeFirstServe(env.batch_size, n_agents)
    td = env.reset()
    b, n = env.batch_size, n_agents
    acc_r, acc_t = torch.zeros(b, n, dtype=torch.float64), torch.zeros(b, n, dtype=torch.float64)
    drawn = torch.zeros(b, n, dtype=torch.float64)
    total = 0.0
    for _ in range(300):
        starting = td["agents", "acting"].clone()
        td = env.step(rule(env.agent_rows(td)).view(b, n))
        # the duration drawn for each action that started at this step
        drawn = torch.where(starting, env.to_end + td["duration"][:, None].double(), drawn)
        acc_r += td["reward"][:, None].double()
        acc_t += td["duration"][:, None].double()
        acting = td["agents", "acting"]
        got_r, got_t = td["agents", "reward"].double(), td["agents", "duration"].double()
        assert torch.allclose(got_r[acting], acc_r[acting], atol=1e-4)
        assert torch.allclose(got_t[acting], acc_t[acting], atol=1e-4)
        assert torch.allclose(got_t[acting], drawn[acting], atol=1e-4)
        assert bool((got_r[~acting] == 0).all() & (got_t[~acting] == 0).all())
        assert bool(acting.any(1).all())  # every step ends at least one action
        acc_r = torch.where(acting, 0.0, acc_r)
        acc_t = torch.where(acting, 0.0, acc_t)
        total += float(td["parts_delivered"].sum())
    assert total > 0


def test_several_events_in_one_long_advance_are_processed_in_time_order():
    # long idles (about 10 s), arrivals every ~2 s and 2.5 s assemblies: several of each per
    # advance; every step draws the same numbers, so the loop runs a fixed number of rounds
    timing = FourAGVTiming(
        idle_mean=10.0,
        idle_var=0.01,
        interarrival_mean=2.0,
        interarrival_var=0.01,
        assembly_mean=(2.5, 2.5, 2.5, 2.5),
        assembly_var=0.01,
    )
    env = FourAGVEnv([5], 256, n_agents=1, timing=timing)
    longest, shortest = 10.0 + 6 * 0.1, 2.0 - (3 * 0.01) ** 0.5
    assert env._events_per_step == 1 + int(longest // shortest) == 6
    env.reset()
    put(env, drop_off=[[3, 3, 3, 3]])
    td = act(env, IDLE)  # machines start at this epoch and finish all three parts (7.5 s)
    assert bool((buffers(td, "pick_up") == 3).all()) and bool((buffers(td, "drop_off") == 0).all())
    assert not bool(env.busy.any())
    ages = td["pick_up_age"]  # oldest first, 2.5 s apart
    assert bool((ages[..., 0] > ages[..., 1]).all() & (ages[..., 1] > ages[..., 2]).all())
    gaps = ages[..., :-1] - ages[..., 1:]  # assembly times 2 and 3 (cut at -+6 std = 0.6 s)
    assert bool(((gaps - 2.5).abs() <= 0.6 + 1e-4).all())
    assert abs(float(gaps.mean()) - 2.5) < 0.01
    first = td["duration"][:, None] - ages[..., 0]  # assembly time 1
    assert bool(((first - 2.5).abs() <= 0.6 + 1e-4).all())
    arrivals, time = 0.0, 0.0
    for _ in range(30):
        env.warehouse.zero_()
        td = act(env, IDLE)
        arrivals += float(buffers(td, "warehouse").sum() + td["parts_lost"].sum())
        time += float(td["duration"].sum())
    assert abs(arrivals / time - 0.5) < 0.01  # one arrival per 2 s, each counted once


# ---------------------------------------------------------------- distributions (Table 6.1)
def moments(x):
    return float(x.double().mean()), float(x.double().var())


def test_distributions_match_table_6_1():
    env = FourAGVEnv([0], 4096)
    gaps = torch.cat([env._draw_gap() for _ in range(25)])
    m, v = moments(gaps)
    assert abs(m - 4.0) < 0.01 and abs(v - 1.0) < 0.02
    assert float(gaps.min()) >= 4 - 3**0.5 - 1e-6 and float(gaps.max()) <= 4 + 3**0.5 + 1e-6
    kinds = torch.cat([env._draw_part_type() for _ in range(25)])
    frac = torch.bincount(kinds, minlength=4).double() / len(kinds)
    assert torch.allclose(
        frac, torch.tensor([0.20, 0.28, 0.22, 0.30], dtype=torch.float64), atol=0.005
    )
    asm = torch.cat([env._draw_assembly() for _ in range(25)])
    for i, mean in enumerate((15.0, 24.0, 24.0, 30.0)):
        m, v = moments(asm[:, i])
        assert abs(m - mean) < 0.02 and abs(v - 2.0) < 0.05
    idle = torch.full((4096, 4), IDLE)
    t = torch.cat([env._draw_action_time(idle) for _ in range(10)]).flatten()
    m, v = moments(t)
    assert abs(m - 1.0) < 0.003 and abs(v - 0.1) < 0.004 and float(t.min()) > 0
    for a in (FORWARD, LEFT, RIGHT, LOAD, UNLOAD):
        t = torch.cat([env._draw_action_time(torch.full((4096, 4), a)) for _ in range(3)])
        m, _ = moments(t)
        assert abs(m - 0.001) < 1e-5 and float(t.min()) > 0 and float(t.max()) < 0.002
    slow = FourAGVEnv([0], 4096, timing=FIGURE_6_5)
    t = torch.cat([slow._draw_action_time(torch.full((4096, 4), FORWARD)) for _ in range(10)])
    m, v = moments(t)
    assert abs(m - 2.0) < 0.003 and abs(v - 0.1) < 0.004
    assert env._events_per_step == 1 and slow._events_per_step == 2


def test_arrival_rate_and_mix_through_the_dynamics():
    env = FourAGVEnv([7], 256, n_agents=2)
    env.reset()
    counts, time = torch.zeros(4), 0.0
    for _ in range(200):
        env.warehouse.zero_()  # empty bays: every arrival shows up
        td = act(env, IDLE, IDLE)
        counts += buffers(td, "warehouse").sum(0).float()
        time += float(td["duration"].sum())
        assert float(td["parts_lost"].sum()) == 0
    frac = counts / counts.sum()
    assert torch.allclose(frac, torch.tensor([0.20, 0.28, 0.22, 0.30]), atol=0.02), frac
    assert abs(time / float(counts.sum()) - 4.0) < 0.1


def items_in_the_system(td):
    """``[B]`` parts and assemblies inside the factory: bays, buffers, machines and AGVs."""
    held = sum(buffers(td, name).sum(-1) for name in ("warehouse", "drop_off", "pick_up"))
    return held + (td["agents", "status"] != EMPTY).sum(-1)


def test_parts_are_conserved_under_a_noisy_dispatcher():
    # parts that arrived = parts and assemblies in the system + delivered + lost; with Table 6.1
    # an advance holds at most one arrival, so a step had one iff the arrival timer was refilled
    b = 32
    env = FourAGVEnv([0, 1], b // 2)
    rule = FirstComeFirstServe(env.batch_size, 4)
    noise = BatchRNG([0, 1], b // 2, "noise")
    td = env.reset()
    arrived, delivered, lost = torch.zeros(b), torch.zeros(b), torch.zeros(b)
    for _ in range(1500):
        action = rule(env.agent_rows(td)).view(b, 4)
        explore = noise.uniform(4) < 0.2
        action = torch.where(explore, noise.integers(N_ACTIONS, 4), action)
        timer = env.to_arrival.clone()
        td = env.step(action)
        arrived += (env.to_arrival > timer - td["duration"].double() + 1e-3).float()
        delivered += td["assemblies_delivered"]
        lost += td["parts_lost"]
        assert torch.equal(arrived, items_in_the_system(td) + delivered + lost)
        assert bool((buffers(td, "drop_off") <= 3).all() & (buffers(td, "pick_up") <= 3).all())
    assert float(delivered.sum()) > 0 and float(lost.sum()) > 0


def test_time_limit_truncates_and_resets_every_agent():
    env = FourAGVEnv([0], 4, max_episode_steps=5)
    td = env.reset()
    for t in range(1, 7):
        td = env.step(torch.full((4, 4), FORWARD))
        assert bool(td["truncated"].all()) == (t == 5)
        if t == 6:
            assert bool(td["is_init"].all()) and bool(td["agents", "acting"].all())
            assert bool((td["agents", "location"] == WAREHOUSE_DROP).all())
            assert float(td["duration"].sum()) == 0


# ---------------------------------------------------------------- determinism
def rollout(seeds, e, steps, noise_seed=11, state=None):
    """Outputs of a noisy-dispatcher rollout (and the state to resume from at ``state``)."""
    env = FourAGVEnv(seeds, e)
    rule = FirstComeFirstServe(env.batch_size, 4)
    noise = BatchRNG(seeds, e, f"noise{noise_seed}")
    td = env.reset()
    out, saved = [], None
    for t in range(steps):
        if t == state:
            saved = (env.state_dict(), rule.state_dict(), noise.state_dict(), td.clone())
        action = rule(env.agent_rows(td)).view(env.batch_size, 4)
        action = torch.where(noise.uniform(4) < 0.3, noise.integers(N_ACTIONS, 4), action)
        td = env.step(action)
        out.append(td)
    return out, saved, (env, rule, noise)


def test_population_equals_separate_runs_bit_for_bit():
    seeds, e, steps = [3, 1, 4], 4, 250
    together, _, _ = rollout(seeds, e, steps)
    for p, s in enumerate(seeds):
        alone, _, _ = rollout([s], e, steps)
        for t in range(steps):
            mine = together[t][p * e : (p + 1) * e]
            for key in mine.keys(include_nested=True, leaves_only=True):
                assert torch.equal(mine[key], alone[t][key]), (s, t, key)


def test_state_dict_round_trip_continues_identically():
    steps, cut = 300, 120
    full, saved, (env, rule, noise) = rollout([0, 1], 4, steps, state=cut)
    env_state, rule_state, noise_state, td = copy.deepcopy(saved)
    env.load_state_dict(env_state)
    rule.load_state_dict(rule_state)
    noise.load_state_dict(noise_state)
    for t in range(cut, steps):
        action = rule(env.agent_rows(td)).view(env.batch_size, 4)
        action = torch.where(noise.uniform(4) < 0.3, noise.integers(N_ACTIONS, 4), action)
        td = env.step(action)
        for key in td.keys(include_nested=True, leaves_only=True):
            assert torch.equal(td[key], full[t][key]), (t, key)


def test_bad_arguments():
    with pytest.raises(ValueError, match="capacity"):
        FourAGVEnv([0], 1, capacity=0)
    with pytest.raises(ValueError, match="n_agents"):
        FourAGVEnv([0], 1, n_agents=0)
    env = FourAGVEnv([0], 2)
    env.reset()
    with pytest.raises(ValueError, match="outside the action space"):
        env.step(torch.full((2, 4), N_ACTIONS))
    assert TABLE_6_1.part_mix == (0.20, 0.28, 0.22, 0.30)
