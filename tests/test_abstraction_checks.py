"""Dietterich's safe-abstraction conditions (hrl_torch.analysis.abstraction) on small models.

Each condition is flagged on a model built to break it and silent once the model or the
abstraction is mended; the repository's taxi and small AGV hierarchies are checked as they are.
"""

import re
from pathlib import Path

import torch

from agents.small_agv import small_agv_hierarchy
from agents.taxi import Navigate, get_and_put, taxi_hierarchy, taxi_primitives
from envs import agv_small as agv
from envs import taxi
from hrl_torch import analysis as A
from hrl_torch.analysis.abstraction import (
    LEAF_IRRELEVANCE,
    MAX_NODE_IRRELEVANCE,
    RESULT_DISTRIBUTION_IRRELEVANCE,
)
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask


def model_of(next_state, reward):
    return A.FiniteModel.from_tables(
        torch.tensor(next_state), torch.tensor(reward, dtype=torch.float64), lambda s: {"s": s}
    )


def state(o):
    return o["s"]


def is_in(*states):
    return lambda o: torch.isin(o["s"], torch.tensor(states))


def summary(violations):
    return [(v.condition, v.subtask, v.child, v.abstract_state, v.states) for v in violations]


# ----------------------------------------------------------------------------- Condition 2
# one action "right": 0 -> 1 -> 2 -> 3 (the root ends at 3); -1, -1, then +10 into 3
CHAIN = model_of([[1], [2], [3], [3]], [[-1.0], [-1.0], [10.0], [0.0]])


def chain_graph(right_states):
    abstract = state if right_states > 1 else None
    root = Subtask("Root", ["right"], 4, abstract=state, terminated=is_in(3))
    return TaskGraph("Root", [root, Primitive("right", 0, right_states, abstract)], 1)


def test_leaf_irrelevance_flags_a_single_state_primitive_whose_reward_varies():
    (v,) = A.check_abstractions(chain_graph(1), CHAIN)
    assert summary([v]) == [(LEAF_IRRELEVANCE, "right", None, 0, (0, 2))]
    assert "-1 and 10" in v.message
    assert A.check_abstractions(chain_graph(4), CHAIN) == []


# ----------------------------------------------------------------------------- Condition 1
# state = 2 * pos + flag. step: from pos 0 to pos 1 (Go ends) if flag == 0, else stay;
# flip: toggles the flag. Go's abstraction keeps pos only.
def flag_model(step_ignores_flag):
    stay = 3 if step_ignores_flag else 1
    return model_of([[2, 1], [stay, 0], [2, 3], [3, 2]], [[-1.0, -1.0]] * 4)


def flag_graph(go_states):
    go = Subtask(
        "Go",
        ["step", "flip"],
        go_states,
        abstract=(lambda o: o["s"] // 2) if go_states == 2 else state,
        terminated=lambda o: o["s"] >= 2,
    )
    root = Subtask("Root", ["Go"], 4, abstract=state, terminated=lambda o: o["s"] >= 2)
    return TaskGraph("Root", [root, go, Primitive("step", 0), Primitive("flip", 1)], 2)


def test_max_node_irrelevance_flags_a_dropped_variable_the_dynamics_read():
    found = A.check_abstractions(flag_graph(2), flag_model(step_ignores_flag=False))
    assert summary(found) == [
        (MAX_NODE_IRRELEVANCE, "Go", "step", 0, (0, 1)),
        (MAX_NODE_IRRELEVANCE, "Go", "flip", 0, (0, 1)),
    ]
    assert "'step' leads to {Go ends} from 0 and to {1} from 1" in found[0].message


def test_max_node_irrelevance_flags_a_dropped_variable_a_later_reward_reads():
    # step: 0 -> 2, 1 -> 3, then 2 -> 4 (-1) and 3 -> 4 (-5); Go merges {0, 1} and {2, 3}
    model = model_of([[2], [3], [4], [4], [4]], [[-1.0], [-1.0], [-1.0], [-5.0], [0.0]])
    go = Subtask("Go", ["step"], 3, abstract=lambda o: o["s"] // 2, terminated=is_in(4))
    root = Subtask("Root", ["Go"], 5, abstract=state, terminated=is_in(4))
    step = Primitive("step", 0, 5, state)  # its own table keeps every state
    found = A.check_abstractions(TaskGraph("Root", [root, go, step], 1), model)
    assert summary(found) == [(MAX_NODE_IRRELEVANCE, "Go", "step", 0, (0, 1))]


def test_max_node_irrelevance_holds_when_the_dropped_variable_is_irrelevant():
    assert A.check_abstractions(flag_graph(2), flag_model(step_ignores_flag=True)) == []
    assert A.check_abstractions(flag_graph(4), flag_model(step_ignores_flag=False)) == []


# state = 2 * pos + hint, pos in 0..2. Walk (left, right) ends at pos 0 or 2; then the root's
# reset goes back to pos 1 (+5 from pos 0, -5 from pos 2). The root drops the hint.
def hint_graph(walk_sees_hint):
    walk = Subtask(
        "Walk",
        ["left", "right"],
        6 if walk_sees_hint else 3,
        abstract=state if walk_sees_hint else (lambda o: o["s"] // 2),
        terminated=lambda o: o["s"] // 2 != 1,
    )
    root = Subtask(
        "Root",
        ["Walk", "reset"],
        3,
        abstract=lambda o: o["s"] // 2,
        child_mask=lambda o: torch.stack([o["s"] // 2 == 1, o["s"] // 2 != 1], 1),
    )
    reset = Primitive("reset", 2, 6, state)
    return TaskGraph("Root", [root, walk, Primitive("left", 0), Primitive("right", 1), reset], 3)


def test_max_node_irrelevance_counts_what_the_children_see():
    # a Walk policy that reads the hint ends left or right by it: C(Root, s, .) depends on it
    left_right_reset = [[max(s - 2, s % 2), min(s + 2, 4 + s % 2), 2 + s % 2] for s in range(6)]
    model = model_of(left_right_reset, [[-1.0, -1.0, 5.0 if s < 2 else -5.0] for s in range(6)])
    assert summary(A.check_abstractions(hint_graph(walk_sees_hint=True), model)) == [
        (RESULT_DISTRIBUTION_IRRELEVANCE, "Root", "Walk", 1, (2, 3)),
        (MAX_NODE_IRRELEVANCE, "Root", "reset", 0, (0, 1)),
        (MAX_NODE_IRRELEVANCE, "Root", "reset", 2, (4, 5)),
    ]
    assert A.check_abstractions(hint_graph(walk_sees_hint=False), model) == []


# ----------------------------------------------------------------------------- Conditions 3, 4
# A (0) and B (1) are merged by the root. go: A -> X (2); B -> Y (3) or, in the "same result"
# variant, B -> A. back (the root's, only at X and Y): X -> A (+5), Y -> B (-5).
A0, B0, X0, Y0 = range(4)


def two_starts_model(same_result):
    b_go = A0 if same_result else Y0
    return model_of(
        [[X0, A0], [b_go, B0], [X0, A0], [Y0, B0]], [[-1.0, 0], [-1, 0], [0, 5], [0, -5]]
    )


def two_starts_graph(root_ends_at_xy=False, pseudo_at_x=None):
    go = Subtask("Go", ["go"], 4, abstract=state, terminated=is_in(X0, Y0))
    root = Subtask(
        "Root",
        ["Go", "back"],
        3,
        abstract=lambda o: (o["s"] - 1).clamp_min(0),  # A, B -> 0; X -> 1; Y -> 2
        terminated=is_in(X0, Y0) if root_ends_at_xy else None,
        child_mask=lambda o: torch.stack([o["s"] < 2, o["s"] >= 2], 1),
        pseudo_reward=(lambda o: (o["s"] == X0) * pseudo_at_x) if pseudo_at_x else None,
    )
    back = Primitive("back", 1, 4, state)  # its reward depends on the state
    return TaskGraph("Root", [root, go, Primitive("go", 0), back], 2)


def test_result_distribution_irrelevance_flags_a_child_ending_in_different_states():
    (v,) = A.check_abstractions(two_starts_graph(), two_starts_model(same_result=False))
    assert summary([v]) == [(RESULT_DISTRIBUTION_IRRELEVANCE, "Root", "Go", 0, (0, 1))]
    assert "'Go' can end in {2} from 0 and in {3} from 1" in v.message


def test_result_distribution_irrelevance_licenses_a_certain_result_only_undiscounted():
    # from A Go takes one step to X, from B two: their values differ, their result does not
    graph, model = two_starts_graph(), two_starts_model(same_result=True)
    assert A.check_abstractions(graph, model) == []
    (v,) = A.check_abstractions(graph, model, gamma=0.9)
    assert summary([v]) == [(RESULT_DISTRIBUTION_IRRELEVANCE, "Root", "Go", 0, (0, 1))]
    assert "gamma < 1" in v.message


def test_termination_licenses_a_merge_when_the_parent_ends_with_the_child():
    model = two_starts_model(same_result=False)
    for gamma in (1.0, 0.9):  # C(Root, s, Go) = 0 everywhere: no durations involved
        assert (
            A.check_abstractions(two_starts_graph(root_ends_at_xy=True), model, gamma=gamma) == []
        )
    # ... unless the parent's pseudo-rewards where it ends differ
    (v,) = A.check_abstractions(two_starts_graph(root_ends_at_xy=True, pseudo_at_x=1.0), model)
    assert summary([v]) == [(RESULT_DISTRIBUTION_IRRELEVANCE, "Root", "Go", 0, (0, 1))]
    assert "{Root ends (pseudo-reward 1)} from 0 and in {Root ends} from 1" in v.message


# ----------------------------------------------------------------------------- Condition 5
# step: 0 -> 1 -> 2 (Inner ends), 3 -> 3. Inner merges 0 and 3, which step tells apart.
SHIELD = model_of([[1], [2], [2], [3]], [[-1.0]] * 4)


def shield_graph(root_ends_at_3):
    inner = Subtask(
        "Inner",
        ["step"],
        3,
        abstract=lambda o: torch.where(o["s"] == 3, 0, o["s"]),
        terminated=is_in(2),
    )
    root = Subtask(
        "Root", ["Inner"], 4, abstract=state, terminated=is_in(2, 3) if root_ends_at_3 else is_in(2)
    )
    return TaskGraph("Root", [root, inner, Primitive("step", 0)], 1)


def test_shielding_drops_states_where_an_ancestor_has_ended():
    found = A.check_abstractions(shield_graph(root_ends_at_3=False), SHIELD)
    assert summary(found) == [(MAX_NODE_IRRELEVANCE, "Inner", "step", 0, (0, 3))]
    assert A.check_abstractions(shield_graph(root_ends_at_3=True), SHIELD) == []


# ----------------------------------------------------------------------------- taxi
def taxi_model(dietterich_putdown):
    """Gymnasium's taxi, or Dietterich's: a putdown away from the destination is illegal."""
    next_state, reward, _, starts = taxi.transition_tables()
    next_state, reward = next_state.clone(), reward.clone()
    if dietterich_putdown:
        elsewhere = (next_state[:, taxi.DROPOFF] != torch.arange(taxi.N_STATES)) & (
            reward[:, taxi.DROPOFF] == -1
        )
        next_state[elsewhere, taxi.DROPOFF] = elsewhere.nonzero().squeeze(1)
        reward[elsewhere, taxi.DROPOFF] = -10.0
    return A.FiniteModel.from_tables(next_state, reward, taxi.decode), starts


def test_taxi_abstractions_are_safe_with_dietterichs_putdown():
    model, starts = taxi_model(dietterich_putdown=True)
    assert A.check_abstractions(taxi_hierarchy(), model, starts) == []


def test_taxi_root_abstraction_breaks_under_gymnasiums_putdown():
    # gymnasium leaves the passenger at any station: Put can end at the pickup station, so
    # C(Root, s, Put) depends on where the taxi stands, which Root's abstraction drops
    model, starts = taxi_model(dietterich_putdown=False)
    found = A.check_abstractions(taxi_hierarchy(), model, starts)
    assert [(v.condition, v.subtask, v.child) for v in found] == [
        (RESULT_DISTRIBUTION_IRRELEVANCE, "Root", "Put")
    ] * 4
    assert [v.abstract_state for v in found] == [4 * 4 + d for d in range(4)]  # in taxi, dest d
    in_taxi_at_g = taxi.encode(0, 4, 4, 0)
    assert found[0].states == (taxi.encode(0, 0, 4, 0), in_taxi_at_g)
    dropped_at_g = taxi.encode(0, 4, 1, 0)
    assert f"in {{0, {dropped_at_g}}} from {in_taxi_at_g}" in found[0].message


def test_taxi_pickup_with_one_state_breaks_leaf_irrelevance():
    prims = [
        p if p.name != "Pickup" else Primitive("Pickup", taxi.PICKUP) for p in taxi_primitives()
    ]
    navs = [Navigate(t) for t in range(4)]
    root = Subtask(
        "Root", ["Get", "Put"], 20, abstract=lambda o: o["passenger"] * 4 + o["destination"]
    )
    graph = TaskGraph("Root", [root, *get_and_put([n.name for n in navs]), *navs, *prims], 6)
    model, starts = taxi_model(dietterich_putdown=True)
    (v,) = A.check_abstractions(graph, model, starts)
    assert (v.condition, v.subtask) == (LEAF_IRRELEVANCE, "Pickup")
    assert v.message.endswith("differ: -10 and -1")


# ----------------------------------------------------------------------------- small AGV
def test_small_agv_abstractions_are_safe_and_a_single_state_unload_is_not():
    model = A.FiniteModel.from_tables(*agv.transition_tables(), agv.decode)
    graph = small_agv_hierarchy()
    assert A.check_abstractions(graph, model) == []
    unload = graph.index["Unload"]
    nodes = [Primitive("Unload", 5) if k == unload else n for k, n in enumerate(graph.nodes)]
    (v,) = A.check_abstractions(TaskGraph("Root", nodes, agv.N_ACTIONS), model)
    assert (v.condition, v.subtask) == (LEAF_IRRELEVANCE, "Unload")
    assert v.message.endswith("differ: 1 and 20")  # part 2 at G2 earns 1, part 1 at G1 20


# ----------------------------------------------------------------------------- the docs
def test_the_docs_example_prints_what_the_docs_show(capsys):
    doc = Path(__file__).resolve().parents[1] / "docs" / "your-own-hierarchy.md"
    section = doc.read_text().split("## Checking your abstractions")[1]
    script = re.findall(r"```python\n(.*?)```", section, flags=re.S)[0]
    shown = re.findall(r"```text\n(.*?)```", section, flags=re.S)[0]
    exec(compile(script, "your-own-hierarchy.md", "exec"), {})
    assert capsys.readouterr().out == shown
