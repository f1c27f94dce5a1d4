"""The discount trap: a node's initial values come from its own rewards, and a warning names
the nodes a discounted learner starts below zero where their children's durations vary."""

import warnings

import pytest
import torch

from agents import four_agv
from agents.four_agv_text import text_hierarchy
from agents.taxi import taxi_hierarchy
from hrl_torch.learners import MaxQLearner
from hrl_torch.learners.init_check import DiscountTrapWarning, discount_traps, warn_discount_trap
from hrl_torch.multiagent.cooperative import cooperative_graph
from hrl_torch.runs import registry


@pytest.mark.parametrize("algo", ["selfish", "cooperative"])
def test_the_root_of_four_agv_text_starts_at_zero(algo):
    spec = registry.get("four-agv").algos[algo]
    learner = spec.make_learner(spec.make_graph(), 2)
    root = learner.heads["Root"]
    assert torch.count_nonzero(root["C"]) == 0
    assert torch.count_nonzero(root["C_int"]) == 0  # was -49.96, the subtasks' step cost
    assert four_agv.internal_init() == pytest.approx(-49.96, abs=0.01)  # at gamma 0.97
    gamma = spec.learner.kwargs.get("gamma", four_agv.GAMMA)  # 0.8 per second now
    pessimism = four_agv.internal_init(gamma=gamma)
    assert pessimism == pytest.approx(-49.7, abs=0.1)
    for job in ("DM_1", "DA_4"):  # the step-cost subtasks keep their own pessimism
        c_int = learner.heads[job]["C_int"]
        assert torch.allclose(c_int, torch.full_like(c_int, pessimism))
        assert torch.count_nonzero(learner.heads[job]["C"]) == 0
    assert discount_traps(learner) == []  # and nothing is left for the warning to name


def _taxi(init: float, gamma: float) -> MaxQLearner:
    return MaxQLearner(taxi_hierarchy(), 1, gamma=gamma, init=init)


def _warned(learner, **kwargs) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warn_discount_trap(learner, **kwargs)
    return [str(w.message) for w in caught if issubclass(w.category, DiscountTrapWarning)]


def test_the_warning_fires_on_a_negative_discounted_start_with_variable_durations():
    (text,) = _warned(_taxi(-5.0, 0.9))
    # Root, Get and Put have subtask children (their durations vary); Navigate's are moves
    names = [name for name, _ in discount_traps(_taxi(-5.0, 0.9))]
    assert names == ["Root", "Get", "Put"]
    assert "Root (-5)" in text and "Navigate" not in text and "gamma 0.9" in text
    # in continuous time every child's duration varies: the navigation nodes too
    timed = [name for name, _ in discount_traps(_taxi(-5.0, 0.9), continuous=True)]
    assert set(timed) > set(names) and any(name.startswith("Navigate") for name in timed)


@pytest.mark.parametrize(("init", "gamma"), [(-5.0, 1.0), (0.0, 0.9), (5.0, 0.9)])
def test_no_warning_undiscounted_or_without_a_negative_start(init, gamma):
    assert _warned(_taxi(init, gamma)) == []
    assert _warned(_taxi(init, gamma), continuous=True) == []


def test_no_warning_where_durations_cannot_vary():
    # flat taxi: one root over the moves, discrete time, every child takes one step
    from agents.taxi import flat_graph

    assert _warned(MaxQLearner(flat_graph(), 1, gamma=0.9, init=-5.0)) == []


def test_a_node_starting_negative_after_training_began_is_named_too():
    learner = MaxQLearner(cooperative_graph(text_hierarchy(), *_coop()), 1, gamma=0.9)
    assert discount_traps(learner) == []
    learner.heads["Root"]["C"][0, 3, 1] = -1.0
    assert [name for name, _ in discount_traps(learner)] == ["Root"]


def _coop():
    from agents.four_agv_text import COOPERATION

    return COOPERATION, 4


def test_hrl_torch_check_prints_the_warning_per_algorithm():
    from hrl_torch.runs.cli import _start_warnings

    (line,) = _start_warnings(registry.get("trash"), "selfish")
    assert "Root (-10)" in line and "gamma 0.95" in line
    assert _start_warnings(registry.get("four-agv"), "selfish") == []
