import math

import pytest
import torch
from tensordict import TensorDict

from agents.small_agv import small_agv_hierarchy
from envs import agv_small as agv
from hrl_torch import analysis as A
from hrl_torch.execution.executor import HierarchicalExecutor
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError, Primitive, Subtask


def model_of(next_state, reward):
    return A.FiniteModel.from_tables(
        torch.tensor(next_state), torch.tensor(reward), lambda s: {"observation": s}
    )


def by_state(o):
    return o["observation"]


def flat_graph(n_states, n_actions):
    names = [f"a{k}" for k in range(n_actions)]
    root = Subtask("Root", names, n_states, abstract=by_state)
    return TaskGraph("Root", [root, *(Primitive(n, k) for k, n in enumerate(names))], n_actions)


def pass_through_graph(n_states, n_actions):
    """Root -> Inner -> primitives, Inner never ends: constrains nothing."""
    names = [f"a{k}" for k in range(n_actions)]
    root = Subtask("Root", ["Inner"], n_states, abstract=by_state)
    inner = Subtask("Inner", names, n_states, abstract=by_state)
    return TaskGraph(
        "Root", [root, inner, *(Primitive(n, k) for k, n in enumerate(names))], n_actions
    )


# ----------------------------------------------------------------------------- Markov chains
def test_chain_gain_of_a_periodic_cycle():
    p = torch.tensor([[0, 1, 0], [0, 0, 1], [1, 0, 0]], dtype=torch.float64)
    res = A.markov_chain_gain(p, torch.tensor([1.0, 2.0, 6.0]))
    assert torch.allclose(res.gain, torch.full((3,), 3.0, dtype=torch.float64))
    assert res.recurrent_class.tolist() == [0, 0, 0]


def test_chain_gain_per_recurrent_class_and_absorption():
    # 0 -> {1, 2} half and half; 1 absorbing (reward 1); 2 <-> 3 (rewards 4, 0); 4 -> 0
    p = torch.zeros(5, 5, dtype=torch.float64)
    p[0, 1] = p[0, 2] = 0.5
    p[1, 1] = p[2, 3] = p[3, 2] = p[4, 0] = 1.0
    res = A.markov_chain_gain(p, torch.tensor([7.0, 1.0, 4.0, 0.0, -3.0]))
    assert torch.allclose(res.gain, torch.tensor([1.5, 1.0, 2.0, 2.0, 1.5], dtype=torch.float64))
    assert res.recurrent_class.tolist() == [-1, 0, 1, 1, -1]
    assert sorted(res.class_gain.tolist()) == [1.0, 2.0]


# ----------------------------------------------------------------------------- a two-exit task
# A (0) -left-> X (1), A -right-> Y' (2) -> Y (3); X and Y go back to A. Every step -1 except
# leaving X (0) and leaving Y (+10). Subtask Go ends at X or Y: its nearest exit is X.
A_, X, Y1, Y = range(4)
TWO_EXITS = model_of([[X, Y1], [A_, A_], [Y, Y], [A_, A_]], [[-1, -1], [0, 0], [-1, -1], [10, 10]])


def two_exit_graph(root_terminal=None):
    go = Subtask(
        "Go",
        ["left", "right"],
        4,
        abstract=by_state,
        terminated=lambda o: (o["observation"] == X) | (o["observation"] == Y),
    )
    root = Subtask("Root", ["Go", "left"], 4, abstract=by_state, terminated=root_terminal)
    return TaskGraph("Root", [root, go, Primitive("left", 0), Primitive("right", 1)], 2)


def two_exit_table(graph, go_at_a):
    table = torch.zeros(graph.n_instances, 4, dtype=torch.long)  # Root: Go where available
    table[1, A_] = go_at_a  # instance 1 is Root/Go
    return table


def test_policy_gain_of_the_two_exit_task_by_hand():
    g = two_exit_graph()
    assert [g.instance_path(k) for k in (0, 1)] == ["Root", "Root/Go"]
    right = A.policy_gain(g, TWO_EXITS, two_exit_table(g, 1))
    left = A.policy_gain(g, TWO_EXITS, two_exit_table(g, 0))
    assert right[A_] == pytest.approx(8 / 3)  # A -> Y' -> Y -> A: -1 - 1 + 10 in 3 steps
    assert left[A_] == pytest.approx(-1 / 2)  # A -> X -> A: -1 + 0 in 2 steps
    assert torch.allclose(right[[X, Y]], torch.full((2,), 8 / 3, dtype=torch.float64))


def test_two_exit_task_hierarchical_beats_recursive():
    g = two_exit_graph()
    ho, ro = A.hierarchically_optimal(g, TWO_EXITS), A.recursively_optimal(g, TWO_EXITS)
    assert ho.gain == pytest.approx(8 / 3)
    assert A.flat_optimal(TWO_EXITS).gain == pytest.approx(8 / 3)
    assert ho.table[1, A_] == 1  # in context, Go takes the long way to the reward
    assert ro.table[g.index["Go"], A_] == 0  # on its own criterion, the nearest exit
    assert ro.value[g.index["Go"], A_] == -1.0  # projected value of Go at A: one step
    assert ro.root_gain == pytest.approx(-1 / 2) and ro.gain[A_] == pytest.approx(-1 / 2)
    assert torch.allclose(ho.policy_gain[A_], torch.tensor(8 / 3, dtype=torch.float64))


def test_episodic_root_value():
    g = two_exit_graph(root_terminal=lambda o: (o["observation"] == X) | (o["observation"] == Y))
    starts = torch.tensor([A_])
    assert A.policy_value(g, TWO_EXITS, two_exit_table(g, 1), starts=starts)[A_] == -2.0
    half = A.policy_value(g, TWO_EXITS, two_exit_table(g, 1), gamma=0.5, starts=starts)
    assert half[A_] == -1.5 and half[[X, Y1, Y]].isnan().all()
    ho = A.hierarchically_optimal(g, TWO_EXITS, starts=starts)
    assert math.isnan(ho.gain) and ho.value[A_] == -1.0 and ho.table[1, A_] == 0


# ----------------------------------------------------------------------------- loops off the path
# a0: 0 -> 1 -> 2 (the root ends at 2), 3 -> 3; a1: 0 -> 3 -> 2. Rewards of a0: -1, 5, 0, -1.
LOOPY = model_of([[1, 3], [2, 1], [2, 2], [3, 2]], [[-1, -2], [5, 0], [0, 0], [-1, 7]])


def loopy_graph():
    names = ["a0", "a1"]
    root = Subtask("Root", names, 4, abstract=by_state, terminated=lambda o: o["observation"] == 2)
    return TaskGraph("Root", [root, *(Primitive(n, k) for k, n in enumerate(names))], 2)


def root_table(g, choices):
    table = torch.zeros(g.n_instances, 4, dtype=torch.long)
    table[0] = torch.tensor(choices)
    return table


def test_policy_value_ignores_a_loop_the_policy_never_reaches():
    g = loopy_graph()
    table = root_table(g, [0, 0, 0, 0])  # a0 everywhere: state 3 loops, but 0 -> 1 -> 2
    starts = torch.tensor([0])
    assert A.policy_value(g, LOOPY, table, starts=starts)[0] == -1 + 5
    half = A.policy_value(g, LOOPY, table, gamma=0.5, starts=starts)
    assert half[0] == -1 + 0.5 * 5 and half[1:].isnan().all()


def test_policy_value_names_the_loop_it_reaches():
    g = loopy_graph()
    table = root_table(g, [1, 0, 0, 0])  # a1 from 0 into state 3, where a0 loops
    with pytest.raises(ValueError, match="'Root' in state 3, where it loops"):
        A.policy_value(g, LOOPY, table, starts=torch.tensor([0]))
    half = A.policy_value(g, LOOPY, table, gamma=0.5, starts=torch.tensor([0]))
    assert half[0] == pytest.approx(-2 + 0.5 * -1 / (1 - 0.5))  # discounted, it is defined


def test_a_root_stuck_at_the_episode_end_asks_for_a_terminated_predicate():
    go = Subtask(
        "Go",
        ["left", "right"],
        4,
        abstract=by_state,
        terminated=lambda o: (o["observation"] == X) | (o["observation"] == Y),
    )
    root = Subtask("Root", ["Go"], 4, abstract=by_state)  # no terminated: stuck where Go ends
    g = TaskGraph("Root", [root, go, Primitive("left", 0), Primitive("right", 1)], 2)
    with pytest.raises(GraphError, match=r"in state 1, .*\(Go: terminated\).*`terminated`"):
        A.policy_value(g, TWO_EXITS, torch.zeros(2, 4, dtype=torch.long), starts=torch.tensor([0]))


# ----------------------------------------------------------------------------- random MDPs
def random_model(seed, n_states=6, n_actions=3):
    gen = torch.Generator().manual_seed(seed)
    p = torch.softmax(3 * torch.randn(n_states, n_actions, n_states, generator=gen), -1)
    reward = torch.randn(n_states, n_actions, generator=gen, dtype=torch.float64)
    obs = TensorDict({"observation": torch.arange(n_states)}, batch_size=[n_states])
    return A.FiniteModel(p.double(), reward, obs)


@pytest.mark.parametrize("seed", range(4))
def test_hierarchy_that_does_not_constrain_is_flat_optimal(seed):
    m = random_model(seed)
    flat = A.flat_optimal(m)
    for graph in (flat_graph(6, 3), pass_through_graph(6, 3)):
        ho = A.hierarchically_optimal(graph, m)
        assert ho.gain == pytest.approx(flat.gain, abs=1e-8)
        assert torch.allclose(ho.policy_gain, torch.tensor(flat.gain, dtype=torch.float64))
    ro = A.recursively_optimal(flat_graph(6, 3), m)  # a lone root: recursive is flat too
    assert ro.root_gain == pytest.approx(flat.gain, abs=1e-8)


@pytest.mark.parametrize("seed", range(4))
def test_hierarchical_at_least_recursive_at_most_flat(seed):
    m = random_model(seed)
    gen = torch.Generator().manual_seed(100 + seed)
    ends = torch.rand(6, generator=gen) < 0.4
    ends[0], ends[1] = True, False

    def terminated(o):
        return ends[o["observation"]]

    sub = Subtask("T", ["a0", "a1", "a2"], 6, abstract=by_state, terminated=terminated)
    root = Subtask("Root", ["T", "a0"], 6, abstract=by_state)
    g = TaskGraph("Root", [root, sub, *(Primitive(f"a{k}", k) for k in range(3))], 3)
    ho, ro, flat = A.hierarchically_optimal(g, m), A.recursively_optimal(g, m), A.flat_optimal(m)
    assert ro.root_gain <= ho.gain + 1e-8 <= flat.gain + 2e-8
    assert torch.allclose(ro.gain, torch.tensor(ro.root_gain, dtype=torch.float64), atol=1e-8)


def test_a_hierarchy_that_can_get_stuck_is_an_error():
    g = TaskGraph(
        "Root",
        [
            Subtask("Root", ["T"], 4, abstract=by_state),
            Subtask(
                "T",
                ["left"],
                4,
                abstract=by_state,
                child_mask=lambda o: (o["observation"] != Y1)[:, None],
            ),
            Primitive("left", 0),
            Primitive("right", 1),
        ],
        2,
    )
    with pytest.raises(GraphError, match="get stuck"):
        A.hierarchically_optimal(g, TWO_EXITS)


# ----------------------------------------------------------------------------- the small AGV
P1, P2 = agv.CELLS.index((0, 5)), agv.CELLS.index((2, 5))  # machine-room sides of D1, D2


@pytest.fixture(scope="module")
def agv_solved():
    g = small_agv_hierarchy()
    m = A.FiniteModel.from_tables(*agv.transition_tables(), agv.decode)
    ho, ro = A.hierarchically_optimal(g, m), A.recursively_optimal(g, m)
    return g, m, ho, ro


def machine_room_starts(values):
    return values[agv.MACHINE_ROOM_LOCATIONS * 3]


def delivery_rates(g, m, table):
    out = []
    for part in (1, 2):
        indicator = (agv.delivery_table() == part).double()
        out.append(machine_room_starts(A.policy_gain(g, m.with_reward(indicator), table)))
    return out


def test_agv_gains(agv_solved):
    g, m, ho, ro = agv_solved
    assert ho.gain == pytest.approx(0.75, abs=1e-8)  # 9 per 12 steps
    assert ro.root_gain == pytest.approx(0.15, abs=1e-8)  # 3 per 20 steps
    assert A.flat_optimal(m).gain == pytest.approx(0.75, abs=1e-8)
    assert torch.allclose(machine_room_starts(ho.policy_gain), torch.tensor(0.75).double())
    assert torch.allclose(machine_room_starts(ro.gain), torch.tensor(0.15).double())
    assert ho.consistent.all() and ro.consistent.all()  # the abstractions lose nothing


def test_agv_hierarchically_optimal_policy_always_serves_m1(agv_solved):
    g, m, ho, _ = agv_solved
    part1, part2 = delivery_rates(g, m, ho.table)
    assert torch.allclose(part1, torch.tensor(1 / 12, dtype=torch.float64))
    assert (part2.abs() < 1e-12).all()
    deliver1 = g.node("DeliverPart1")
    back = ho.table[g.inst_children[0, 2], agv.G1 * 2]  # Root/DeliverPart1, empty at G1
    assert deliver1.children_names[int(back)] == "North"  # towards D1, next to M1
    assert int(ho.table[0, agv.encode(P1, 0)]) == 0  # GetPart1


def test_agv_recursively_optimal_policy_alternates(agv_solved):
    g, m, _, ro = agv_solved
    part1, part2 = delivery_rates(g, m, A.instance_table(g, ro.table))
    assert torch.allclose(part1, torch.tensor(1 / 20, dtype=torch.float64))
    assert torch.allclose(part2, torch.tensor(1 / 20, dtype=torch.float64))
    root = g.node("Root").children_names
    assert root[int(ro.table[g.root, agv.encode(P1, 0)])] == "GetPart1"
    assert root[int(ro.table[g.root, agv.encode(P2, 0)])] == "GetPart2"
    back1 = ro.table[g.index["DeliverPart1"], agv.G1 * 2]
    back2 = ro.table[g.index["DeliverPart2"], agv.G2 * 2]
    assert g.node("DeliverPart1").children_names[int(back1)] == "West"  # into D2
    assert g.node("DeliverPart2").children_names[int(back2)] == "West"  # into D1
    assert ro.value[g.index["DeliverPart1"], agv.encode(agv.G1, 0)] == -2.0  # 2 steps out


def simulate(graph, table, steps=600, burn_in=60, envs=4):
    env = agv.SmallAGVEnv([0], envs)
    executor = HierarchicalExecutor(graph, envs, envs)
    policy = A.TablePolicy(graph, table)
    ctx = graph.context(env.reset())
    action = executor.act(ctx, policy, 0)
    reward, delivered = [], []
    for t in range(steps):
        td = env.step(action)
        ctx = graph.context(td)
        executor.observe(td, ctx)
        action = executor.act(ctx, policy, t)
        reward.append(td["reward"])
        delivered.append(td["delivered"])
    window = slice(burn_in, None)
    return torch.stack(reward)[window].mean(0), agv.throughput(torch.stack(delivered)[window])


def test_agv_exact_gains_equal_long_simulations(agv_solved):
    g, m, ho, ro = agv_solved
    weights = m.with_reward(agv.delivery_weight_table())
    for table, gain in ((ho.table, 0.75), (A.instance_table(g, ro.table), 0.15)):
        exact_throughput = 10_000 * machine_room_starts(A.policy_gain(g, weights, table))
        sim_gain, sim_throughput = simulate(g, table)
        assert torch.allclose(sim_gain, torch.tensor(gain), atol=0.01)
        assert torch.allclose(sim_throughput.double(), exact_throughput[0], rtol=0.01)
    assert exact_throughput[0] == pytest.approx(10_500)  # RO: (20 + 1) per 20 steps
