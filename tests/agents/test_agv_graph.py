import pytest
import torch
from tensordict import TensorDict

from agents.agv import (
    DA_STATES,
    DM_STATES,
    NAV_TARGETS,
    ROOT_STATES,
    agv_hierarchy,
    dispatch_action,
    flat_graph,
)
from envs.agv import (
    EMPTY,
    LOC,
    N_ACTIONS,
    N_LOCATIONS,
    N_STATES,
    AGVEnv,
    decode,
    shortest_paths,
)
from hrl_torch.common.rng import BatchRNG
from hrl_torch.execution.executor import HierarchicalExecutor
from hrl_torch.modules.exploration import uniform_choice


def random_obs(n, seed=0, delivery=True):
    g = torch.Generator().manual_seed(seed)
    fields = decode(torch.randint(0, N_STATES, (n,), generator=g))
    fields["delivery"] = torch.randint(0, 7, (n,), generator=g) * delivery
    return TensorDict(fields, batch_size=[n])


def obs_of(**values):
    """One observation: the flat fields (default 0) and ``delivery``."""
    fields = {k: torch.zeros(1, dtype=torch.long) for k in decode(torch.zeros(1))}
    fields["delivery"] = torch.zeros(1, dtype=torch.long)
    for k, v in values.items():
        fields[k] = torch.tensor([v])
    return TensorDict(fields, batch_size=[1])


def test_graph_validates_with_the_stated_abstractions():
    g = agv_hierarchy()
    sizes = {g.names[k]: g.nodes[k].n_states for k in range(g.n_nodes)}
    assert DM_STATES == 33 * 7 * 3 * 2 == 1386 and DA_STATES == 33 * 7 * 3 == 693
    assert ROOT_STATES == 33 * 3**6 * 2**3
    for i in (1, 2, 3):
        assert sizes[f"DM_{i}"] == 1386 and sizes[f"DA_{i}"] == 693
    assert all(sizes[f"Nav_{t}"] == 33 for t in NAV_TARGETS) and len(NAV_TARGETS) == 10
    assert sizes["Root"] == ROOT_STATES
    assert g.node("Root").children_names == ("DM_1", "DM_2", "DM_3", "DA_1", "DA_2", "DA_3", "Idle")
    assert g.node("DM_2").children_names == ("Nav_W_2", "Load", "Nav_D_2", "Unload")
    assert g.node("DA_3").children_names == ("Nav_P_3", "Load", "Nav_WA", "Unload")
    assert g.max_levels == 4  # Root / DM / Nav / primitive
    assert g.n_actions == N_ACTIONS


def test_flat_graph():
    g = flat_graph()
    assert g.node("Root").n_states == N_STATES and len(g.node("Root").children_names) == 5
    obs = random_obs(1000)
    ctx = g.context(obs)
    assert torch.equal(ctx.abstract[:, g.root], obs["observation"])


def test_abstractions_stay_in_range_over_random_states():
    g = agv_hierarchy()
    obs = random_obs(50_000)
    ctx = g.context(obs)  # raises GraphError when an abstraction leaves its range
    assert bool((ctx.abstract < g.node_n_states).all()) and bool((ctx.abstract >= 0).all())
    # ... and each uses the whole range without collisions: a bijection from its variables
    for name, variables in [
        ("DM_2", ("location", "status", "drop_off_2", "warehouse_2")),
        ("DA_1", ("location", "status", "pick_up_1")),
        ("Nav_D_3", ("location",)),
        (
            "Root",
            (
                "location",
                "drop_off_1",
                "drop_off_2",
                "drop_off_3",
                "pick_up_1",
                "pick_up_2",
                "pick_up_3",
                "warehouse_1",
                "warehouse_2",
                "warehouse_3",
            ),
        ),
    ]:
        k = g.index[name]
        key = torch.stack([obs[v] for v in variables], -1)
        pairs = torch.unique(torch.cat([key, ctx.abstract[:, k, None]], -1), dim=0)
        assert len(pairs) == len(torch.unique(key, dim=0)) == len(torch.unique(ctx.abstract[:, k]))


def test_abstractions_cover_exactly_their_range():
    g = agv_hierarchy()
    dm = g.node("DM_1")
    loc, st, d, w = torch.meshgrid(
        torch.arange(33), torch.arange(7), torch.arange(3), torch.arange(2), indexing="ij"
    )
    obs = TensorDict(
        {
            "location": loc.flatten(),
            "status": st.flatten(),
            "drop_off_1": d.flatten(),
            "warehouse_1": w.flatten(),
        },
        [loc.numel()],
    )
    assert torch.equal(dm.abstract(obs).sort().values, torch.arange(DM_STATES))
    da = g.node("DA_2")
    loc, st, p = torch.meshgrid(torch.arange(33), torch.arange(7), torch.arange(3), indexing="ij")
    obs = TensorDict(
        {"location": loc.flatten(), "status": st.flatten(), "pick_up_2": p.flatten()}, [loc.numel()]
    )
    assert torch.equal(da.abstract(obs).sort().values, torch.arange(DA_STATES))


def flags(g, name, **values):
    node = g.node(name)
    o = obs_of(**values)
    return bool(node.initiable(o)), bool(node.terminated(o))


def test_initiation_and_termination_predicates():
    g = agv_hierarchy()
    # DM_1: needs part 1 in the warehouse and room in D1 (or part 1 already on board)
    assert flags(g, "DM_1", warehouse_1=1) == (True, False)
    assert flags(g, "DM_1", warehouse_1=1, drop_off_1=2) == (False, True)
    assert flags(g, "DM_1", warehouse_1=0) == (False, True)
    assert flags(g, "DM_1", warehouse_2=1) == (False, True)
    assert flags(g, "DM_1", status=1) == (True, False)
    assert flags(g, "DM_1", status=1, drop_off_1=2) == (True, False)  # waits for room
    assert flags(g, "DM_1", status=2, warehouse_1=1) == (False, True)
    assert flags(g, "DM_1", warehouse_1=1, delivery=1, location=LOC["D1"]) == (True, True)
    assert flags(g, "DM_1", warehouse_1=1, delivery=2)[1] is False
    # DA_2: needs an assembly in P2 (or assembly 2 on board); ends when it is delivered
    assert flags(g, "DA_2", pick_up_2=1) == (True, False)
    assert flags(g, "DA_2", pick_up_2=0) == (False, True)
    assert flags(g, "DA_2", status=5) == (True, False)
    assert flags(g, "DA_2", status=4, pick_up_2=2) == (False, True)
    assert flags(g, "DA_2", delivery=5, pick_up_2=1)[1] is True
    assert flags(g, "DA_2", delivery=4, pick_up_2=1)[1] is False
    # navigation ends at its target only
    assert flags(g, "Nav_W_3", location=LOC["W3"]) == (True, True)
    assert flags(g, "Nav_W_3", location=LOC["W2"]) == (True, False)


def test_children_are_bound_by_the_status():
    g = agv_hierarchy()
    empty = g.context(obs_of(warehouse_1=1, location=LOC["J2"]))
    k = g.index["DM_1"]
    assert empty.available[0, k, :4].tolist() == [True, True, False, False]
    loaded = g.context(obs_of(status=1, location=LOC["J2"]))
    assert loaded.available[0, k, :4].tolist() == [False, False, True, True]
    at_bay = g.context(obs_of(warehouse_1=1, location=LOC["W1"]))
    assert at_bay.available[0, k, :4].tolist() == [False, True, False, False]
    root = g.context(obs_of())
    assert root.available[0, g.root, :7].tolist() == [False] * 6 + [True]  # only Idle


class ScriptedPolicy:
    """Nav: shortest path; DM/DA: the first available child; Root: random available child."""

    def __init__(self, graph, rng):
        self.g, self.rng = graph, rng
        target = torch.full((graph.n_nodes,), -1)
        for t, loc in NAV_TARGETS.items():
            target[graph.index[f"Nav_{t}"]] = loc
        self.target = target
        self.first = shortest_paths()[1]

    def new_step(self):
        width = self.g.max_children  # one block per push level and step, as ValuePolicy
        self.u = self.rng.uniform(self.g.max_levels * width).view(-1, self.g.max_levels, width)

    def select(self, inst, ctx, available, step, push):
        node = self.g.inst_node[inst.clamp_min(0)]
        target = self.target[node]
        move = self.first[ctx.obs["location"], target.clamp_min(0)]
        first_available = available.long().argmax(-1)
        random = uniform_choice(available, self.u[:, push])
        choice = torch.where(
            target >= 0, move, torch.where(node == self.g.root, random, first_available)
        )
        return choice, torch.ones_like(choice, dtype=torch.bool)


STEPS = {False: 300, True: 300}


@pytest.mark.parametrize("continuous", [False, True])
def test_every_subtask_terminates_under_a_scripted_policy(continuous):
    g = agv_hierarchy()
    env = AGVEnv([0, 1], 32, continuous=continuous)
    ex = HierarchicalExecutor(g, env.batch_size, env.envs_per_learner)
    policy = ScriptedPolicy(g, BatchRNG([0, 1], 32, "script"))
    td = env.reset()
    ctx = g.context(td)
    delivered = 0.0
    for t in range(STEPS[continuous]):
        deciding = ex.stack.top <= 0  # the root chooses in these rows
        assert bool((td["status"][deciding] == EMPTY).all())  # why Root ignores the status
        action = ex.act(ctx, policy, t)
        td = env.step(action)
        ctx = g.context(td)
        ex.observe(td, ctx)
        delivered += float(td["assemblies_delivered"].sum())
    successes = ex.stats.successes.sum(0)
    for k in g.subtasks():
        if k != g.root:
            assert successes[k] > 0, g.names[k]
    assert delivered > 0


def test_dispatch_rule_only_uses_valid_actions():
    obs = random_obs(5000, delivery=False)
    action = dispatch_action(obs)
    assert int(action.min()) >= 0 and int(action.max()) < N_ACTIONS
    assert N_LOCATIONS == 33
