"""The per-entry visit-count step size ``alpha_n = clip(1 / n, low, high)`` (``VisitCount``)."""

import pytest
import torch

from agents.taxi import taxi_hierarchy
from hrl_torch.learners import MaxQLearner, SMDPQLearner
from hrl_torch.modules.schedules import VisitCount
from hrl_torch.modules.tables import TableBank


def _bank(init: float = 7.0) -> TableBank:
    return TableBank(1, torch.tensor([4]), torch.tensor([1]), init, visits=True)


def _hit(bank, entries, targets, steps, distinct):
    index = torch.tensor(entries)
    mask = torch.ones_like(index, dtype=torch.bool)
    bank.update(index, torch.tensor(targets), steps, mask, distinct)


@pytest.mark.parametrize("distinct", [True, False])
def test_one_over_n_holds_the_running_mean_of_a_hand_checked_sequence(distinct):
    bank, steps = _bank(), VisitCount()
    # entry 0 starts at 7; targets 2, 4, 9, 1: alpha 1, 1/2, 1/3, 1/4
    expected = [2.0, 3.0, 5.0, 4.0]  # 2; 2 + (4-2)/2; 3 + (9-3)/3; 5 + (1-5)/4
    for target, want in zip([2.0, 4.0, 9.0, 1.0], expected, strict=True):
        _hit(bank, [0], [target], steps, distinct)
        assert bank.data[0, 0].item() == pytest.approx(want)
    assert bank.visits[:4].tolist() == [4.0, 0.0, 0.0, 0.0]
    assert bank.data[0, 1:].tolist() == [7.0, 7.0, 7.0]  # untouched entries keep their start


def test_the_floor_and_the_ceiling_clip_one_over_n():
    bank, steps = _bank(0.0), VisitCount(low=0.25, high=0.5)
    # alpha: clip(1/1) = 0.5, clip(1/2) = 0.5, 1/3, 1/4, clip(1/5) = 0.25, 0.25
    w = 0.0
    for alpha in [0.5, 0.5, 1 / 3, 0.25, 0.25, 0.25]:
        _hit(bank, [2], [12.0], steps, True)
        w += alpha * (12.0 - w)
        assert bank.data[0, 2].item() == pytest.approx(w)


def test_same_step_hits_move_an_entry_as_successive_updates_would():
    steps = VisitCount(low=0.1)
    one_by_one, at_once = _bank(), _bank()
    for target in [3.0, 5.0]:  # two earlier visits
        _hit(one_by_one, [1], [target], steps, True)
        _hit(at_once, [1], [target], steps, True)
    for target in [6.0, 6.0, 6.0]:  # three more, agreeing: exact in one batch
        _hit(one_by_one, [1], [target], steps, True)
    _hit(at_once, [1, 1, 1, 3], [6.0, 6.0, 6.0, -2.0], steps, False)
    assert at_once.data[0, 1].item() == pytest.approx(one_by_one.data[0, 1].item())
    assert at_once.data[0, 1].item() == pytest.approx((3 + 5 + 18) / 5)
    assert at_once.data[0, 3].item() == -2.0 and at_once.visits[:4].tolist() == [0, 5, 0, 1]


def test_masked_rows_count_nothing_and_bad_ranges_are_refused():
    bank = _bank()
    index, target = torch.tensor([0, 1]), torch.tensor([1.0, 1.0])
    bank.update(index, target, VisitCount(), torch.tensor([True, False]))
    assert bank.visits[:2].tolist() == [1.0, 0.0] and bank.data[0, 1].item() == 7.0
    with pytest.raises(ValueError, match="low <= high"):
        VisitCount(low=0.5, high=0.2)
    with pytest.raises(ValueError, match="count visits"):
        TableBank(1, torch.tensor([4]), torch.tensor([1])).update(
            index, target, VisitCount(), torch.tensor([True, True])
        )


@pytest.mark.parametrize("make", [MaxQLearner, SMDPQLearner])
def test_a_tabular_learner_given_visit_count_counts_its_entries(make):
    learner = make(taxi_hierarchy(), 2, alpha=VisitCount(low=0.05))
    store = learner.tables if hasattr(learner, "tables") else learner.Q
    assert store.counts_visits and store.visits.shape == store.store.shape
    assert "visits" in "".join(learner.state_dict())  # (saved with the learner)
