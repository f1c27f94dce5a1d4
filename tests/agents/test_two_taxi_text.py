"""The text's two-taxi task (Section 6.6): a race's loser returns empty; rules; registration."""

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from agents.two_taxi import two_taxi_hierarchy
from agents.two_taxi_rules import DIST, NONE, RulePolicy, measure
from envs.two_taxi import EMPTY, NORTH, PICKUP, STATION_LOC, WAIT, TwoTaxiEnv
from hrl_torch.env.multiagent_env import agent_rows
from hrl_torch.runs import registry
from tests.agents.test_two_taxi_graph import obs
from tests.envs.test_two_taxi import place, step

torch.set_num_threads(1)
R, G, Y, B = range(4)


def _get_b_of_taxi_1(graph, td):
    """(GetB terminated, GetB available at Root) for taxi 1 of the single env row."""
    ctx = graph.context(agent_rows(td)[1:2])
    col, root = graph.index["GetB"], graph.index["Root"]
    return bool(ctx.terminated[0, col]), bool(ctx.available[0, root, 0])


@pytest.mark.parametrize("text", [True, False])
def test_the_loser_of_a_race_drives_on_and_returns_empty(text):
    """Both taxis go for B's passenger; taxi 0 is there first. With the text's rule taxi 1's
    GetB runs on to B and ends there, empty; in the first build it ends at the pickup."""
    graph = two_taxi_hierarchy(text)
    env = TwoTaxiEnv([0], 1, mean_interarrival=float("inf"))
    env.reset()
    place(env, [23, 13], passengers={B: Y})  # taxi 1 two moves north of B (13 -> 18 -> 23)
    td = step(env, WAIT, WAIT)
    assert _get_b_of_taxi_1(graph, td) == (False, True)  # both may start GetB
    td = step(env, PICKUP, 0)  # taxi 0 takes the passenger; taxi 1 drives south
    assert td["agents", "status"].tolist() == [[Y, EMPTY]] and td["waiting_B"].item() == 0
    terminated, available = _get_b_of_taxi_1(graph, td)
    assert terminated == (not text)  # text: the loser does not know yet; it drives on
    assert not available  # nobody new can start GetB: nobody waits at B
    td = step(env, NORTH, 0)  # taxi 1 reaches B
    assert td["agents", "taxi_loc"][0, 1].item() == int(STATION_LOC[B])
    assert td["agents", "status"][0, 1].item() == EMPTY  # it returns empty
    assert _get_b_of_taxi_1(graph, td) == (True, False)  # its GetB ends at B


def test_a_passenger_who_arrives_before_the_loser_is_picked_up_by_it():
    """Section 6.6: "a new passenger arrives after the first taxi picked up the previous one
    and before the second taxi reaches the station. This passenger will be picked up by the
    second taxi": with someone waiting at B when the loser arrives, its GetB goes on."""
    graph = two_taxi_hierarchy(text=True)
    env = TwoTaxiEnv([0], 1, mean_interarrival=float("inf"))
    env.reset()
    place(env, [12, 23], status=[Y, EMPTY], passengers={B: G})  # taxi 1 at B, someone waits
    td = step(env, WAIT, WAIT)
    assert _get_b_of_taxi_1(graph, td) == (False, True)
    td = step(env, WAIT, PICKUP)
    assert td["agents", "status"].tolist() == [[Y, G]]
    assert _get_b_of_taxi_1(graph, td)[0]  # ended with the pickup


def _rollout(rule, steps=400, rows=64, **env_options):
    env = TwoTaxiEnv([5], rows, **env_options)
    policy = RulePolicy(env, rule)
    env.reset()
    out = []
    for _ in range(steps):
        action = policy.act()
        out.append((policy.task.clone(), env.taxi_loc.clone(), env.status.clone(), action))
        env.step(action)
    return out


def test_coordinated_rule_never_sends_two_taxis_to_one_station():
    both = 0
    for task, *_ in _rollout("coordinated", mean_interarrival=3):
        same = (task[:, 0] == task[:, 1]) & (task[:, 0] != NONE)
        both += int(same.sum())
    assert both == 0
    races = 0
    for task, *_ in _rollout("race", mean_interarrival=3):
        races += int(((task[:, 0] == task[:, 1]) & (task[:, 0] != NONE)).sum())
    assert races > 0  # the racing rule does


def test_race_rule_loser_drives_to_the_station_and_only_then_chooses_again():
    env = TwoTaxiEnv([0], 1, mean_interarrival=float("inf"))
    policy = RulePolicy(env, "race")
    env.reset()
    place(env, [23, 13], passengers={B: Y, R: G})
    assert policy.act().tolist() == [[PICKUP, 0]]  # both go for B, the nearer passenger
    env.step(torch.tensor([[PICKUP, 0]]))
    assert policy.act()[0, 1].item() == 0 and policy.task[0, 1].item() == B  # on to B
    env.step(torch.tensor([[NORTH, 0]]))
    assert env.taxi_loc[0, 1].item() == int(STATION_LOC[B])
    action = policy.act()  # at B with nobody there: its task ends and it heads for R
    assert policy.task[0, 1].item() == R and action[0, 1].item() != PICKUP
    taken = RulePolicy(env, "race-taken")  # the first build's Get: gives up at once
    place(env, [23, 13], passengers={B: Y, R: G})
    taken.act()
    env.step(torch.tensor([[PICKUP, 0]]))
    taken.act()
    assert taken.task[0, 1].item() == R


def test_shortest_paths_and_rule_measurement():
    assert DIST[0, 4].item() == 8 and DIST[0, 20].item() == 4 and DIST[20, 23].item() == 7
    assert (DIST == DIST.T).all()  # walls block both ways
    result = measure("coordinated", seeds=(0, 1), rows=2, steps=300, burn_in=20)
    assert len(result["throughput"]) == 2 and all(t > 0 for t in result["throughput"])
    with pytest.raises(ValueError, match="rule"):
        RulePolicy(TwoTaxiEnv([0], 1), "nearest")


def test_text_domains_are_registered_with_team_rewards_and_their_arrivals():
    for name, arrivals in (("two-taxi", "grid"), ("two-taxi-station", "station")):
        domain = registry.get(name)
        assert {"selfish", "cooperative", "com-0", "com-10", "single"} <= set(domain.algos)
        spec = domain.algos["cooperative"]
        env = domain.make_env([0], 2, "torch", **spec.env_options)
        assert env.arrivals == arrivals and not env.own_rewards
        # the text's Get: away from B it runs on with nobody at B
        graph = domain.algos["selfish"].make_graph()
        ctx = graph.context(obs(taxi_loc=12))
        assert not ctx.terminated[0, graph.index["GetB"]]
    old = registry.get("two-taxi-earlier").make_env([0], 2, "torch")
    assert old.own_rewards and old.arrivals == "grid"
    assert WAIT == 6


def test_text_navigation_masks_moves_into_walls_and_costs_more_per_move():
    graph = two_taxi_hierarchy(text=True)
    ctx = graph.context(obs(taxi_loc=7))  # (1, 2): a wall to the west
    nav = graph.index["Navigate_R"]
    assert ctx.available[0, nav, :4].tolist() == [True, True, True, False]  # N, S, E, not W
    corner = graph.context(obs(taxi_loc=0)).available[0, nav, :4]  # R itself ends Navigate_R
    assert corner.tolist() == [False, True, True, False]
    node = graph.node("Navigate_B")
    action = torch.tensor([0])
    assert node.shaping_reward(obs(), action, obs()).item() == -5.0
    old = two_taxi_hierarchy().node("Navigate_B")  # the first build: -1, every move allowed
    assert old.shaping_reward(obs(), action, obs()).item() == -1.0
    assert two_taxi_hierarchy().context(obs(taxi_loc=7)).available[0, nav, :4].all()


def test_coordinated_choices_need_to_see_the_same_steps_choices():
    """Two free taxis, one passenger: matched, only the nearer goes; unseen, both race."""
    for rule, tasks in (("coordinated", [[B, NONE]]), ("coordinated-unseen", [[B, B]])):
        env = TwoTaxiEnv([0], 1, mean_interarrival=float("inf"))
        policy = RulePolicy(env, rule)
        env.reset()
        place(env, [18, 13], passengers={B: Y})  # taxi 0 one move from B, taxi 1 two
        action = policy.act()
        assert policy.task.tolist() == tasks, rule
        assert action[0, 1].item() == (WAIT if rule == "coordinated" else 0)
    env = TwoTaxiEnv([0], 1, mean_interarrival=float("inf"))
    policy = RulePolicy(env, "coordinated-unseen")
    env.reset()
    place(env, [18, 13], passengers={B: Y})
    policy.task[0, 0] = B  # taxi 0 chose B at an earlier step: taxi 1 sees it and waits
    policy.act()
    assert policy.task.tolist() == [[B, NONE]]
