"""The ``four-agv`` variant: committed waiting jobs, buffer-level root, team reward,
per-AGV rules without reservations."""

import pytest
import torch
from tensordict import TensorDict

from agents import four_agv, four_agv_text
from agents.four_agv import da_states, dm_states
from agents.four_agv_rules import DISPATCH_RULES, FirstComeFirstServe
from agents.four_agv_text import (
    ROOT_STATES,
    PerAGVRule,
    root_abstract,
    text_hierarchy,
)
from envs.four_agv import (
    BAYS,
    DROP_OFF,
    FIGURE_6_5,
    IDLE,
    LOAD,
    PICK_UP,
    UNLOAD,
    WAREHOUSE_DROP,
    FourAGVEnv,
    decode,
    n_flat_states,
)
from hrl_torch.multiagent.cooperative import cooperative_graph
from hrl_torch.runs import registry

FAR = 1e6


def obs_of(n=1, **values):
    """``n`` agent rows: every field 0 except ``values`` (one value or one per row)."""
    fields = {k: torch.zeros(n, dtype=torch.long) for k in decode(torch.zeros(1))}
    fields["delivery"] = torch.zeros(n, dtype=torch.long)
    for k, v in values.items():
        fields[k] = torch.as_tensor(v).expand(n).clone()
    return TensorDict(fields, batch_size=[n])


def observe(env):
    """The observation of the env's current state, every agent acting (no step taken)."""
    zero, no = torch.zeros(env.batch_size), torch.zeros(env.batch_size, dtype=torch.bool)
    return env.agent_rows(env._output(zero, zero, no, no, no, torch.zeros(env.acting.shape)))


# ---------------------------------------------------------------- graph
def test_state_counts_and_the_root_reads_buffer_levels():
    g = text_hierarchy()
    assert g.node("Root").n_states == ROOT_STATES == 6**4 == 1_296
    assert g.node("DM_1").n_states == dm_states() == 100 * 9 * 4 * 2
    assert g.node("DA_4").n_states == da_states() == 100 * 9 * 4
    assert g.node("DA_2").children_names == ("Nav_P_2", "Load", "Nav_WA", "Unload", "Idle")
    assert g.node("Root").children_names == (
        *(f"DM_{i}" for i in range(1, 5)),
        *(f"DA_{i}" for i in range(1, 5)),
    )
    coop = cooperative_graph(g, four_agv_text.COOPERATION, 4)
    assert coop.node("Root").n_states == 1_296 * 9**3
    # every root state is reached, and P1's three levels give three different states
    fields = decode(torch.arange(0, n_flat_states(), 9_973))
    states = root_abstract(TensorDict(fields, batch_size=fields["location"].shape))
    assert int(states.min()) >= 0 and int(states.max()) < ROOT_STATES
    assert len(set(states.tolist())) == ROOT_STATES
    levels = [int(root_abstract(obs_of(pick_up_1=p))) for p in (0, 1, 2, 3)]
    assert levels[1] == levels[2] and len(set(levels)) == 3
    ready = obs_of(warehouse_2=1, drop_off_2=2)
    assert int(root_abstract(ready)) != int(root_abstract(obs_of(warehouse_2=1, drop_off_2=3)))


def test_the_smaller_root_sees_pi_empty_or_not():
    small = text_hierarchy(root_levels=2)
    assert small.node("Root").n_states == 4**4 == 256
    fields = decode(torch.arange(0, n_flat_states(), 9_973))
    states = root_abstract(TensorDict(fields, batch_size=fields["location"].shape), levels=2)
    assert len(set(states.tolist())) == 256 and int(states.max()) < 256
    levels = [int(root_abstract(obs_of(pick_up_1=p), levels=2)) for p in (0, 1, 2, 3)]
    assert levels[0] != levels[1] == levels[2] == levels[3]
    with pytest.raises(ValueError, match="root_levels"):
        text_hierarchy(root_levels=4)


def test_jobs_are_committed_and_wait_at_an_empty_bay_or_a_full_buffer():
    g = text_hierarchy()
    dm, da = g.node("DM_1"), g.node("DA_3")
    # may start with nothing to fetch; does not end when the item is gone, only on delivery
    nothing = obs_of()
    assert bool(dm.initiable(nothing)) and not bool(da.initiable(nothing))
    assert not bool(dm.initiable(obs_of(drop_off_1=3)))  # no room in D1 now
    assert bool(da.initiable(obs_of(drop_off_3=1)))  # an assembly is on its way
    assert bool(da.initiable(obs_of(pick_up_3=1))) and bool(da.initiable(obs_of(status=7)))
    assert not bool(dm.terminated(nothing)) and not bool(dm.terminated(obs_of(drop_off_1=3)))
    assert not bool(da.terminated(obs_of(drop_off_3=1)))  # waits for the machine
    assert bool(da.terminated(nothing))  # nothing can come any more
    assert bool(dm.terminated(obs_of(delivery=1))) and bool(da.terminated(obs_of(delivery=7)))
    # at an empty bay only Idle (wait); at a bay with the part only Load
    names = dm.children_names
    at_empty_bay = dm.child_mask(obs_of(location=BAYS[0]))[0]
    assert [names[k] for k in range(5) if at_empty_bay[k]] == ["Idle"]
    at_bay = dm.child_mask(obs_of(location=BAYS[0], warehouse_1=1))[0]
    assert [names[k] for k in range(5) if at_bay[k]] == ["Load"]
    # with part 1 at a full D1: wait; with room: unload
    full = dm.child_mask(obs_of(location=DROP_OFF[0], status=1, drop_off_1=3))[0]
    assert [names[k] for k in range(5) if full[k]] == ["Idle"]
    room = dm.child_mask(obs_of(location=DROP_OFF[0], status=1, drop_off_1=2))[0]
    assert [names[k] for k in range(5) if room[k]] == ["Unload"]
    # DA_3 at an empty P3: wait; with an assembly: load
    names = da.children_names
    empty_p = da.child_mask(obs_of(location=PICK_UP[2]))[0]
    assert [names[k] for k in range(5) if empty_p[k]] == ["Idle"]
    some = da.child_mask(obs_of(location=PICK_UP[2], pick_up_3=1))[0]
    assert [names[k] for k in range(5) if some[k]] == ["Load"]


# ---------------------------------------------------------------- team reward
@pytest.mark.parametrize(("domain", "each"), [("four-agv", 2.0), ("four-agv-earlier", 1.0)])
def test_every_agent_receives_the_team_s_reward(domain, each):
    env = registry.get(domain).make_env([0], 1, n_agents=2)
    env.reset()
    env.to_arrival.fill_(FAR)
    env.location[:] = WAREHOUSE_DROP
    env.status[:] = torch.tensor([[5, 8]])  # both carry an assembly

    def until_both_acted(first):
        got, acted = torch.zeros(2), torch.zeros(2, dtype=torch.bool)
        td = env.step(torch.tensor([first]))
        while True:
            got += td["agents", "reward"][0]
            acted |= td["agents", "acting"][0]
            if bool(acted.all()):
                return got.tolist(), float(td["reward"])
            td = env.step(torch.tensor([[IDLE, IDLE]]))

    got, _ = until_both_acted([UNLOAD, UNLOAD])
    assert got == [each, each]  # team: 2 each; own: 1 each
    # an agent that idled while the other delivered: the team's reward, or nothing of its own
    env.status[:] = torch.tensor([[5, 0]])
    got, _ = until_both_acted([UNLOAD, IDLE])
    assert got == [1.0, 1.0 if each == 2.0 else 0.0]


# ---------------------------------------------------------------- per-AGV rules
def test_per_agv_rules_take_the_same_job_without_reservation():
    # three free agents at WA; part 1 waits and D1 has room for one part only
    env = FourAGVEnv([0], 1, n_agents=3)
    env.reset()
    env.warehouse[0] = torch.tensor([1, 0, 0, 0])
    env.drop_off[0] = torch.tensor([2, 0, 0, 0])
    for name in DISPATCH_RULES:
        rule = PerAGVRule(name, 1, 3)
        rule(observe(env))
        assert rule.job.tolist() == [[0, 0, 0]], name  # all three race for part 1
    central = FirstComeFirstServe(1, 3)
    central(observe(env))
    assert central.job.tolist() == [[0, -1, -1]]  # the centralised one claims it once
    # a part on board reserves nothing: with part 1 carried to D1 (room for one), a free AGV
    # still takes the next part 1
    env.status[0] = torch.tensor([1, 0, 0])
    rule = PerAGVRule("fcfs", 1, 3)
    rule(observe(env))
    assert rule.job.tolist()[0][1:] == [0, 0]
    central = FirstComeFirstServe(1, 3)
    central(observe(env))
    assert central.job.tolist()[0][1:] == [-1, -1]


def test_a_lost_race_waits_at_the_bay_and_completes_when_the_next_part_comes():
    env = FourAGVEnv([0], 1, n_agents=2, timing=FIGURE_6_5)
    env.reset()
    env.to_arrival.fill_(FAR)  # no arrivals but the one the test makes
    env.location[0] = torch.tensor([BAYS[0], BAYS[0] - 1])  # agent 0 at W1, agent 1 behind
    env.warehouse[0] = torch.tensor([1, 0, 0, 0])
    rule = PerAGVRule("nsf", 1, 2)
    td = observe(env)
    clock, waits, waited_time, loaded_at = 0.0, 0, 0.0, None
    for _ in range(100):
        action = rule(td).view(1, 2)
        waiting = int(env.location[0, 1]) == BAYS[0] and int(env.status[0, 1]) == 0
        if waiting and bool(td["acting"][1]) and int(env.warehouse[0, 0]) == 0:
            assert int(action[0, 1]) == IDLE and int(rule.job[0, 1]) == 0  # waits, committed
            waits += 1
        elif waiting and bool(td["acting"][1]):
            assert waits >= 3 and int(action[0, 1]) == LOAD  # the new part: load it
        out = env.step(action)
        clock += float(out["duration"])
        waited_time += float(out["duration"]) if waiting else 0.0
        td = env.agent_rows(out)
        if waits == 3 and int(env.warehouse[0, 0]) == 0 and loaded_at is None:
            env.warehouse[0, 0] = 1  # the next part 1 arrives
        if loaded_at is None and int(env.status[0, 1]) == 1:
            loaded_at = clock
        if int(out["agents", "delivery"][0, 1]) == 1:
            break
    assert rule.job.tolist()[0][0] == -1 or int(env.status[0, 0]) != 1  # agent 0 went on
    assert waits >= 3 and waited_time > 2.5  # three ~1 s waits: time passed at the bay
    assert loaded_at is not None  # it loaded the new part ...
    assert int(out["agents", "delivery"][0, 1]) == 1  # ... and delivered it into D1


def test_registered_text_domain_keeps_the_old_one():
    text, old = registry.get("four-agv"), registry.get("four-agv-earlier")
    assert set(text.algos) >= {"cooperative", "selfish", "single", "cooperative-2s", "fcfs"}
    assert text.algos["cooperative"].multiagent is not None
    assert text.algos["selfish-2s"].env_options["timing"] == FIGURE_6_5
    assert old.make_env is four_agv.make_env and text.make_env is four_agv_text.make_env
    env = old.make_env([0], 1)
    assert env.own_rewards and not text.make_env([0], 1).own_rewards
    graph = text.algos["fcfs"].make_graph()
    learner = text.algos["fcfs"].make_learner(graph, 1)
    policy = learner.make_policy(None, _Rng(4), evaluate=True)
    assert isinstance(policy.rule, PerAGVRule)


class _Rng:
    def __init__(self, rows):
        self.batch_size = rows
        self.device = torch.device("cpu")  # where the rule's memory goes


def test_per_agv_rule_waits_at_a_full_drop_off_and_at_an_empty_pick_up():
    env = FourAGVEnv([0], 1, n_agents=2)
    env.reset()
    env.location[0] = torch.tensor([DROP_OFF[1], PICK_UP[2]])
    env.status[0] = torch.tensor([2, 0])
    env.drop_off[0] = torch.tensor([0, 3, 0, 0])
    rule = PerAGVRule("hqf", 1, 2)
    rule.base.job[0, 1] = 6  # DA_3, but P3 is empty
    action = rule(observe(env))
    assert action.tolist() == [IDLE, IDLE]
    env.drop_off[0, 1] = 2
    env.pick_up[0, 2] = 1
    assert rule(observe(env)).tolist() == [UNLOAD, LOAD]


# ---------------------------------------------------------------- issue 33's options
def test_an_idle_at_the_root_commits_to_nothing():
    g = text_hierarchy(root_idle=True)
    root = g.node("Root")
    assert root.children_names[-1] == "Idle" and len(root.children_names) == 9
    assert g.node("Idle").is_primitive
    assert text_hierarchy().node("Root").children_names[-1] == "DA_4"  # the default: no Idle


def test_a_part_reward_pays_the_drop_and_the_throughput_counts_assemblies_only():
    env = four_agv_text.make_env([0], 1, n_agents=2, own_rewards=True, part_reward=1.0)
    env.reset()
    env.to_arrival.fill_(FAR)
    env.location[:] = torch.tensor([[DROP_OFF[0], WAREHOUSE_DROP]])
    env.status[:] = torch.tensor([[1, 5]])  # part 1 at D1, assembly 1 at WA
    td = env.step(torch.tensor([[UNLOAD, UNLOAD]]))
    assert float(td["reward"]) == 2.0  # one part, one assembly
    assert float(four_agv_text.assemblies(td)) == 1.0
    no_part_reward = four_agv_text.make_env([0], 1, n_agents=2, own_rewards=True)
    assert no_part_reward.rewards.part == 0.0
