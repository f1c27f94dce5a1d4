import torch

from hrl_torch.modules.tables import TableBank


def bank(init=0.0):
    return TableBank(2, torch.tensor([3, 0, 2]), torch.tensor([2, 1, 4]), init)


def test_layout_offsets_and_views():
    b = bank()
    assert b.total == 3 * 2 + 2 * 4
    b.view(2, learner=1)[1, 3] = 7.0
    idx = b.index(torch.tensor(1), torch.tensor(2), torch.tensor(1), torch.tensor(3))
    assert float(b.read(idx)) == 7.0
    assert float(b.store[-1]) == 0.0  # the sentinel


def test_same_step_updates_combine_order_free():
    b = bank(init=1.0)
    idx = b.index(
        torch.zeros(4, dtype=torch.long),
        torch.zeros(4, dtype=torch.long),
        torch.tensor([0, 0, 0, 2]),
        torch.tensor([1, 1, 1, 0]),
    )
    target = torch.tensor([4.0, 5.0, 6.0, 10.0])
    mask = torch.tensor([True, True, True, False])
    b.update(idx, target, 0.5, mask)
    rho = (1 - 0.5) ** 3
    assert torch.isclose(b.view(0)[0, 1], torch.tensor(rho * 1.0 + (1 - rho) * 5.0))
    assert float(b.view(0)[2, 0]) == 1.0  # masked row: unchanged
    assert float(b.store[-1]) == 0.0
    # permuting the rows gives the same tables
    b2 = bank(init=1.0)
    perm = torch.tensor([2, 0, 3, 1])
    b2.update(idx[perm], target[perm], 0.5, mask[perm])
    assert torch.equal(b.store, b2.store)


def test_single_update_is_the_textbook_step():
    b = bank(init=2.0)
    idx = b.index(torch.tensor([1]), torch.tensor([0]), torch.tensor([2]), torch.tensor([0]))
    b.update(idx, torch.tensor([4.0]), 0.25, torch.tensor([True]))
    assert float(b.view(0, 1)[2, 0]) == 2.0 + 0.25 * (4.0 - 2.0)
    assert float(b.view(0, 0)[2, 0]) == 2.0  # the other learner's table is untouched


def test_masked_reads_are_zero():
    b = bank(init=3.0)
    idx = torch.tensor([0, 1, 2])
    out = b.read(idx, torch.tensor([True, False, True]))
    assert out.tolist() == [3.0, 0.0, 3.0]


def test_large_tables_group_updates_without_scratch_buffers_and_agree(monkeypatch):
    idx = torch.tensor([0, 3, 3, 3, 7, 0, 13])
    target = torch.tensor([1.0, 2.0, 4.0, 6.0, 3.0, 5.0, 9.0])
    mask = torch.tensor([True, True, True, True, True, False, True])
    small = bank(init=0.5)
    small.update(idx, target, 0.3, mask)
    monkeypatch.setattr(TableBank, "SCRATCH_LIMIT", 0)
    large = bank(init=0.5)
    large.update(idx, target, 0.3, mask)
    assert large._scratch.numel() == 0  # no table-sized buffers
    assert torch.equal(small.store, large.store)
