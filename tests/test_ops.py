"""The hot path's small tensor helpers: both code paths of each equal the plain indexing."""

import math

import pytest
import torch

from hrl_torch.common import ops


@pytest.mark.parametrize("rows", [3, 3000])  # below and above ops.COLUMNS_TRANSPOSED
def test_columns_equals_advanced_indexing(rows):
    g = torch.Generator().manual_seed(rows)
    x = torch.randn(rows, 7, 2, generator=g)
    index = torch.randint(0, 7, (4, 3), generator=g)
    got = ops.columns(x, index)
    assert got.is_contiguous()
    assert torch.equal(got, x[:, index])
    flat = torch.randint(0, 7, (5,), generator=g)
    assert torch.equal(ops.columns(x[..., 0] > 0, flat), (x[..., 0] > 0)[:, flat])


@pytest.mark.parametrize("rows", [5, 2000])  # below and above ops.ADD_AT_FLAT values
def test_add_at_sums_repeated_indices(rows):
    g = torch.Generator().manual_seed(rows)
    table = torch.zeros(4, 3, 6)
    first = torch.arange(4)[:, None, None]
    second = torch.randint(0, 3, (rows, 1), generator=g)
    third = torch.randint(0, 6, (rows, 2), generator=g)
    values = torch.rand(4, rows, 2, generator=g)
    ops.add_at(table, (first, second, third), values)
    expected = torch.zeros(4, 3, 6)
    for k in range(4):
        for r in range(rows):
            for j in range(2):
                expected[k, second[r, 0], third[r, j]] += values[k, r, j]
    assert torch.allclose(table, expected, atol=1e-4)


@pytest.mark.parametrize("shape", [(3, 5), (1000, 7, 5), (64, 2, 6)])  # around ARGMAX_BY_MAX
def test_argmax_last_gives_argmax_on_ties_infinities_and_nans(shape):
    gen = torch.Generator().manual_seed(0)
    x = torch.randint(0, 3, shape, generator=gen).float()  # many exact ties
    for value, p in ((-math.inf, 0.2), (math.inf, 0.02), (math.nan, 0.02)):
        x[torch.rand(shape, generator=gen) < p] = value
    x[0] = -math.inf  # a row with nothing available
    assert torch.equal(ops.argmax_last(x), x.argmax(-1))
    assert torch.equal(ops.argmax_last(x, keepdim=True), x.argmax(-1, keepdim=True))
