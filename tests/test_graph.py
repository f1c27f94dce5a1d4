import pytest
import torch
from tensordict import TensorDict

from agents.taxi import taxi_hierarchy
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError, Primitive, Subtask


def obs(b=3, **fields):
    return TensorDict({k: torch.as_tensor(v) for k, v in fields.items()}, batch_size=[b])


def test_cycle_is_rejected():
    nodes = [
        Subtask("Root", ["A"]),
        Subtask("A", ["B"]),
        Subtask("B", ["A", "go"]),
        Primitive("go", 0),
    ]
    with pytest.raises(GraphError, match="cycle: A -> B -> A"):
        TaskGraph("Root", nodes, n_actions=1)


def test_self_loop_is_rejected():
    with pytest.raises(GraphError, match="cycle"):
        TaskGraph("Root", [Subtask("Root", ["Root", "go"]), Primitive("go", 0)], n_actions=1)


def test_unknown_child_is_rejected():
    with pytest.raises(GraphError, match=r"unknown children \['jump'\]"):
        TaskGraph("Root", [Subtask("Root", ["go", "jump"]), Primitive("go", 0)], n_actions=1)


def test_primitive_outside_action_space_is_rejected():
    with pytest.raises(GraphError, match=r"action 6, outside the env's action space \[0, 6\)"):
        TaskGraph("Root", [Subtask("Root", ["go"]), Primitive("go", 6)], n_actions=6)


def test_subtask_without_children_is_rejected():
    nodes = [Subtask("Root", ["A", "go"]), Subtask("A", []), Primitive("go", 0)]
    with pytest.raises(GraphError, match="'A' has no children"):
        TaskGraph("Root", nodes, n_actions=1)


def test_duplicate_names_and_bad_root_are_rejected():
    with pytest.raises(GraphError, match="duplicate"):
        TaskGraph("Root", [Subtask("Root", ["go"]), Primitive("go", 0), Primitive("go", 0)])
    with pytest.raises(GraphError, match="not a node"):
        TaskGraph("Top", [Subtask("Root", ["go"]), Primitive("go", 0)])
    with pytest.raises(GraphError, match="must be a subtask"):
        TaskGraph("go", [Subtask("Root", ["go"]), Primitive("go", 0)])


def test_abstraction_out_of_range_is_a_clear_error():
    root = Subtask("Root", ["go"], n_states=4, abstract=lambda o: o["x"])
    graph = TaskGraph("Root", [root, Primitive("go", 0)], n_actions=1)
    graph.context(obs(x=[0, 3, 2]))  # in range: fine
    with pytest.raises(
        GraphError, match=r"'Root'.abstract returned 4, outside \[0, 4\) \(env row 1\)"
    ):
        graph.context(obs(x=[0, 4, 2]))
    with pytest.raises(GraphError, match="returned -1"):
        graph.context(obs(x=[-1, 0, 2]))


def test_missing_abstraction_is_a_clear_error():
    graph = TaskGraph("Root", [Subtask("Root", ["go"], n_states=3), Primitive("go", 0)], 1)
    with pytest.raises(GraphError, match="no abstract"):
        graph.context(obs(x=[0, 1, 2]))


def test_taxi_instance_tree_shares_navigate():
    g = taxi_hierarchy()
    paths = [g.instance_path(k) for k in range(g.n_instances)]
    assert "Root/Get/Navigate_R" in paths and "Root/Put/Navigate_R" in paths
    assert sum(p.endswith("/Navigate_B") for p in paths) == 2  # one subtask, two contexts
    assert g.max_levels == 4  # Root, Get/Put, Navigate, primitive
    assert g.n_nodes == 13
    # every instance's children are instances of its node's children, in slot order
    for k in range(g.n_instances):
        node = int(g.inst_node[k])
        for slot, child in enumerate(g.inst_children[k].tolist()):
            if child >= 0:
                assert int(g.inst_node[child]) == int(g.node_children[node, slot])
                assert int(g.inst_parent[child]) == k


def test_availability_combines_mask_termination_and_initiation():
    g = taxi_hierarchy()
    # taxi at R (loc 0), passenger at R waiting, destination G
    o = obs(1, taxi_loc=[0], passenger=[0], destination=[1], observation=[0])
    ctx = g.context(o)
    get = g.index["Get"]
    # Navigate_R is masked in (bound to the passenger) but terminated (taxi already at R)
    assert ctx.available[0, get].tolist()[:5] == [False, False, False, False, True]
    root = g.index["Root"]
    assert ctx.available[0, root, :2].tolist() == [True, False]  # Put: passenger not in taxi
    assert bool(ctx.terminated[0, g.index["Navigate_R"]])
    assert not bool(ctx.terminated[0, g.index["Navigate_G"]])


def test_event_termination_ends_a_run_but_does_not_block_a_start():
    def flag(o):
        return o["event"] == 1

    state_sub = Subtask("ByState", ["go"], terminated=flag)
    event_sub = Subtask("ByEvent", ["go"], terminated=flag, event_termination=True)
    root = Subtask("Root", ["ByState", "ByEvent"])
    g = TaskGraph("Root", [root, state_sub, event_sub, Primitive("go", 0)], n_actions=1)
    ctx = g.context(obs(2, event=[1, 0]))
    assert ctx.terminated[:, 1:3].tolist() == [[True, True], [False, False]]
    assert ctx.blocked[:, 1:3].tolist() == [[True, False], [False, False]]
    assert ctx.available[:, 0, :2].tolist() == [[False, True], [True, True]]


def test_memory_nodes_see_where_their_invocation_started():
    # a subtask that ends two cells right of where it started, rewarded by distance travelled
    def remember(o):
        return o["x"][:, None].float()

    def done(o, memory):
        return o["x"] >= memory[:, 0] + 2

    def pseudo(o, memory):
        return o["x"].float() - memory[:, 0]

    hop = Subtask(
        "Hop", ["go"], terminated=done, remember=remember, memory_size=1, pseudo_reward=pseudo
    )
    g = TaskGraph("Root", [Subtask("Root", ["Hop"]), hop, Primitive("go", 0)], n_actions=1)
    o = obs(2, x=[5, 9])
    memory = torch.zeros(2, g.n_nodes, g.max_memory)
    memory[:, g.index["Hop"], 0] = torch.tensor([3.0, 9.0])
    ctx = g.context(o, memory=memory)
    hop_k = g.index["Hop"]
    assert ctx.terminated[:, hop_k].tolist() == [True, False]
    assert not ctx.blocked[:, hop_k].any()  # a memory node never blocks a start
    pr = g.internal_rewards_at_termination(o, memory)
    assert pr[:, hop_k].tolist() == [2.0, 0.0]


def _tabulable_graph(n_states):
    """Every kind of predicate, all functions of the integer ``observation`` alone."""

    def x(o):
        return o["observation"]

    by_state = Subtask(
        "ByState",
        ["go", "stay"],
        n_states=4,
        abstract=lambda o: x(o) // 3,
        terminated=lambda o: x(o) % 4 == 0,
        initiable=lambda o: x(o) < n_states - 2,
        features=lambda o: torch.stack([x(o) / n_states, (x(o) % 2).float()], 1),
        n_features=2,
    )
    by_event = Subtask(
        "ByEvent", ["go"], terminated=lambda o: x(o) % 3 == 1, event_termination=True
    )
    masked = Subtask(
        "Masked",
        ["go", "stay"],
        terminated=lambda o: x(o) == n_states - 1,
        child_mask=lambda o: torch.stack([x(o) % 2 == 0, x(o) % 2 == 1], 1),
    )
    root = Subtask(
        "Root", ["ByState", "ByEvent", "Masked"], n_states=3, abstract=lambda o: x(o) % 3
    )
    prims = [Primitive("go", 0), Primitive("stay", 1, n_states, x)]
    return TaskGraph("Root", [root, by_state, by_event, masked, *prims], n_actions=2)


def test_a_tabulated_graph_looks_up_exactly_the_context_it_would_compute():
    n = 12
    plain, tabulated = _tabulable_graph(n), _tabulable_graph(n)
    tabulated.tabulate(obs(n, observation=torch.arange(n)))
    batch = obs(
        3 * n, observation=torch.randperm(3 * n, generator=torch.Generator().manual_seed(0)) % n
    )
    want, got = plain.context(batch), tabulated.context(batch)
    # the event node makes terminated and blocked differ (so the test can tell them apart)
    assert not torch.equal(want.terminated, want.blocked)
    for field in ("abstract", "terminated", "blocked", "available", "features"):
        assert torch.equal(getattr(got, field), getattr(want, field)), field
    # only every state once, in order, can be tabulated
    with pytest.raises(GraphError, match="every state once"):
        _tabulable_graph(n).tabulate(obs(n, observation=torch.arange(n).flip(0)))
