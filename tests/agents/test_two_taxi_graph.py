import pytest
import torch
from tensordict import TensorDict

from agents.two_taxi import (
    GET_STATES,
    PUT_STATES,
    ROOT_STATES,
    TEXT_TABLE_SIZES,
    U1,
    count_values,
    table_sizes,
    two_taxi_com_hierarchy,
    two_taxi_hierarchy,
    value_counts,
)
from envs.two_taxi import EMPTY, N_ACTIONS, PICKUP, PUTDOWN, WAIT, TwoTaxiEnv
from tests.agents.test_trash_graph import random_rollout

torch.set_num_threads(1)
R, G, Y, B = range(4)


def obs(**fields):
    """One agent row with the given fields (status default empty, others 0)."""
    keys = (
        "taxi_loc",
        "status",
        "stations",
        "waiting_R",
        "waiting_G",
        "waiting_Y",
        "waiting_B",
        "picked_up",
        "delivered",
        "last_action",
    )
    values = {k: torch.tensor([fields.get(k, EMPTY if k == "status" else 0)]) for k in keys}
    return TensorDict(values, batch_size=[1])


def test_graph_of_figure_6_10():
    g = two_taxi_hierarchy()
    assert g.node("Root").children_names == U1 == ("GetB", "GetG", "GetR", "GetY", "Wait", "Put")
    assert g.node("GetB").children_names == ("Navigate_B", "Pickup")
    assert g.node("GetR").children_names == ("Navigate_R", "Pickup")
    nav = ("Navigate_R", "Navigate_G", "Navigate_Y", "Navigate_B")
    assert g.node("Put").children_names == (*nav, "Putdown")
    for name in nav:
        assert g.node(name).children_names == ("North", "South", "East", "West")
    assert g.node("Root").n_states == ROOT_STATES == 12_800
    assert g.node("GetY").n_states == GET_STATES == 6_400
    assert g.node("Put").n_states == PUT_STATES == 125
    assert [g.node(p).action for p in ("Pickup", "Putdown", "Wait")] == [PICKUP, PUTDOWN, WAIT]
    assert g.n_actions == N_ACTIONS and g.max_levels == 4
    com = two_taxi_com_hierarchy()
    assert com.node("Root").children_names == ("Com", "NotCom")
    assert com.node("Com").children_names == com.node("NotCom").children_names == U1
    assert com.max_levels == 5


def test_table_sizes_against_the_text():
    sizes = table_sizes()
    assert sizes == {"selfish": 135_810, "cooperative": 519_810, "com_cooperative": 622_210}
    assert abs(sizes["selfish"] - TEXT_TABLE_SIZES["selfish"]) < 100
    counts = value_counts(two_taxi_hierarchy())
    assert counts["Root"] == 12_800 * 6 and counts["GetB"] == 6_400 * 2
    assert counts["Put"] == 125 * 5 and counts["Navigate_G"] == 25 * 4
    assert counts["Pickup"] == 6_400 and counts["Wait"] == 256 and counts["North"] == 1
    com = value_counts(two_taxi_com_hierarchy(), {"Com": 6})
    assert (com["Root"], com["Com"], com["NotCom"]) == (12_800 * 2, 12_800 * 36, 12_800 * 6)
    # three taxis: the cooperative Root is indexed by the two others' actions
    assert table_sizes(3)["cooperative"] == sizes["selfish"] + 12_800 * 6 * 35
    with pytest.raises(ValueError, match="Com"):
        count_values(two_taxi_hierarchy(), {"Com": 6})


def test_terminations_masks_and_abstractions_by_hand():
    g = two_taxi_hierarchy()
    rows = TensorDict.cat(
        [
            obs(taxi_loc=23, status=EMPTY, waiting_B=2, stations=2 * 64),  # at B, passenger
            obs(taxi_loc=12, status=G),  # loaded for G in the middle
            obs(taxi_loc=4, status=G),  # loaded, at G
            obs(taxi_loc=7),  # empty, nobody waiting
        ]
    )
    ctx = g.context(rows)
    col = g.index
    assert ctx.terminated[:, col["GetB"]].tolist() == [False, True, True, True]
    assert ctx.terminated[:, col["Put"]].tolist() == [True, False, False, True]
    assert ctx.terminated[:, col["Navigate_B"]].tolist() == [True, False, False, False]
    assert ctx.abstract[:, col["Root"]].tolist() == [
        (23 * 2) * 256 + 128,
        (12 * 2 + 1) * 256,
        (4 * 2 + 1) * 256,
        7 * 2 * 256,
    ]
    assert ctx.abstract[:, col["Put"]].tolist() == [23 * 5 + 4, 12 * 5 + 1, 4 * 5 + 1, 7 * 5 + 4]
    put = ctx.available[:, col["Put"], :5]
    assert put[1].tolist() == [False, True, False, False, False]  # away from G: Navigate(G)
    assert put[2].tolist() == [False, False, False, False, True]  # at G: Putdown
    root = ctx.available[:, col["Root"], :6]
    assert root.tolist() == [
        [True, False, False, False, True, False],  # GetB or Wait
        [False, False, False, False, True, True],  # loaded: Put or Wait
        [False, False, False, False, True, True],
        [False, False, False, False, True, False],  # nothing to do: Wait
    ]
    # Com / NotCom have no termination of their own (the COM agent cuts them after one task)
    com = two_taxi_com_hierarchy()
    events = TensorDict.cat(
        [obs(picked_up=1), obs(delivered=1), obs(last_action=WAIT), obs(last_action=PICKUP)]
    )
    assert not com.context(events).terminated[:, com.index["Com"]].any()


def test_random_hierarchical_rollouts_stay_in_range_and_never_get_stuck():
    env = TwoTaxiEnv([0, 1], 16, mean_interarrival=3)
    ended = random_rollout(two_taxi_hierarchy(), env, 300)
    for pair in [
        ("Root", "GetR"),
        ("Root", "GetB"),
        ("Root", "Put"),
        ("Root", "Wait"),
        ("GetG", "Navigate_G"),
        ("GetY", "Pickup"),
        ("Put", "Putdown"),
        ("Navigate_B", "West"),
    ]:
        assert pair in ended, pair


def test_random_rollouts_of_the_communication_graph():
    env = TwoTaxiEnv([2], 32, mean_interarrival=3)
    ended = random_rollout(two_taxi_com_hierarchy(), env, 300, seed=1)
    # without the COM agent Com / NotCom never end: only their children do
    assert ("Root", "Com") not in ended and ("Root", "NotCom") not in ended
    for pair in [
        ("Com", "GetG"),
        ("NotCom", "Put"),
        ("Com", "Wait"),
        ("Put", "Putdown"),
    ]:
        assert pair in ended, pair


def test_waiting_time_is_the_waits_over_the_deliveries_and_logged_per_seed():
    import agents  # noqa: F401
    from hrl_torch.runs import registry
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    evaluator = registry.get("two-taxi-earlier").make_evaluator(None)
    step = TensorDict(
        {
            "n_delivered": torch.tensor([2, 0, 2]),
            "wait_delivered": torch.tensor([4, 0, 10]),
            "reward": torch.tensor([20.0, -1.0, 40.0]),
            "duration": torch.ones(3),
            "is_init": torch.tensor([False, False, True]),
        },
        batch_size=[3],
    )
    rows = torch.tensor([0, 1, 1])  # learner of each row
    evaluator.observe(step, rows, 2)
    evaluator.observe(step, rows, 2)
    logged = evaluator.flush()
    # learner 0: 4 deliveries in 2 steps that waited 8 steps in all; learner 1: row 2 is a
    # reset (ignored)
    assert logged["charts/wait"][0] == 2.0
    assert logged["charts/wait"][1] != logged["charts/wait"][1]  # no delivery: NaN
    assert logged["charts/throughput"] == [10000.0, 0.0]
    # the trainer's statistics of a multi-agent learner are summed per seed (2 taxis each)
    opts = RunOptions(seeds=[0, 1], envs_per_learner=2, progress=False, tensorboard=False)
    trainer = build_trainer(registry.get("two-taxi-earlier"), "selfish", opts)
    for _ in range(40):
        trainer.train_step()
    calls = trainer.executor.stats.calls  # [4 table sets, nodes]
    assert torch.equal(trainer._per_seed(calls), calls[[0, 2]] + calls[[1, 3]])
