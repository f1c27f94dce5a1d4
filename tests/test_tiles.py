import math

import pytest
import torch

from hrl_torch.modules.tiles import TileCoder, asymmetric_offsets, tile_indices


def test_hand_computed_indices_two_tilings():
    # box [0, 10] x [0, 6], 2 x 3 tiles (widths 5 and 2), tiling 1 shifted by half a tile
    offsets = torch.tensor([[0.0, 0.0], [0.5, 0.5]])
    coder = TileCoder([0.0, 0.0], [10.0, 6.0], [2, 3], n_tilings=2, offsets=offsets)
    x = torch.tensor([[1.0, 1.0], [6.0, 3.9], [9.9, 5.9], [2.6, 0.5]])
    # tiling 0: cells floor(x/5), floor(y/2); tiling 1: floor(x/5 + .5), floor(y/2 + .5), clamped
    expected = torch.tensor(
        [
            [0 * 3 + 0, 6 + 0 * 3 + 1],  # (0.2, 0.5) -> (0,0); (0.7, 1.0) -> (0,1)
            [1 * 3 + 1, 6 + 1 * 3 + 2],  # (1.2, 1.95) -> (1,1); (1.7, 2.45) -> (1,2)
            [1 * 3 + 2, 6 + 1 * 3 + 2],  # (1.98, 2.95) -> (1,2); (2.48->1, 3.45->2)
            [0 * 3 + 0, 6 + 1 * 3 + 0],  # (0.52, 0.25) -> (0,0); (1.02, 0.75) -> (1,0)
        ]
    )
    assert torch.equal(coder(x), expected)


def test_dissertation_sizes():
    coder = TileCoder(
        [0, 0, -180, -15], [150, 150, 180, 15], [5, 5, 36, 5], 9, wrap=[False, False, True, False]
    )
    assert coder.tiles_per_tiling == 4_500
    assert coder.n_features == 40_500


def test_asymmetric_offsets_distinct_per_dimension():
    off = asymmetric_offsets(9, 4)
    assert off.shape == (9, 4)
    assert torch.all((off >= 0) & (off < 1))
    assert torch.equal(off[0], torch.zeros(4))
    for d in range(4):
        assert len(torch.unique(off[:, d])) == 9
    # the displacement vector for 9 tilings skips 3 and 9 (not coprime with 9): (1, 5, 7, 11)
    assert torch.allclose(off[1], torch.tensor([1, 5, 7, 11]) / 9 % 1)
    # powers of two: exactly Sutton & Barto's (1, 3, 5, 7)
    assert torch.allclose(asymmetric_offsets(8, 4)[1], torch.tensor([1, 3, 5, 7]) / 8)


def _coder():
    return TileCoder(
        [0.0, 0.0, -180.0], [150.0, 150.0, 180.0], [5, 4, 36], 9, wrap=[False, False, True]
    )


def test_every_point_one_in_range_index_per_tiling():
    coder = _coder()
    torch.manual_seed(0)
    x = torch.rand(20_000, 3) * torch.tensor([150.0, 150.0, 360.0]) + torch.tensor([0, 0, -180.0])
    idx = coder(x)
    assert idx.shape == (20_000, 9) and idx.dtype == torch.long
    per = coder.tiles_per_tiling
    t = torch.arange(9)
    assert torch.all((idx >= t * per) & (idx < (t + 1) * per))  # one per tiling, distinct


def test_all_tiles_reachable():
    # 4 tilings: edge tiles are at least a quarter tile wide; the grid steps a tenth of a tile
    coder = TileCoder(
        [0.0, 0.0, -180.0], [150.0, 150.0, 180.0], [3, 2, 8], 4, wrap=[False, False, True]
    )
    g = [torch.linspace(0, 150, 31), torch.linspace(0, 150, 21), torch.linspace(-180, 179.9, 81)]
    x = torch.cartesian_prod(*g)
    hit = torch.zeros(coder.n_features, dtype=torch.bool)
    hit[coder(x).flatten()] = True
    assert bool(hit.all())


def test_out_of_box_clamps_to_edge_tiles():
    coder = _coder()
    inside = torch.tensor([[0.0, 150.0, 0.0]])
    outside = torch.tensor([[-40.0, 900.0, 0.0]])
    assert torch.equal(coder(inside), coder(outside))


def test_wrap_around():
    coder = _coder()
    a = coder(torch.tensor([[75.0, 75.0, -180.0]]))
    b = coder(torch.tensor([[75.0, 75.0, 180.0]]))
    c = coder(torch.tensor([[75.0, 75.0, 540.0]]))
    assert torch.equal(a, b) and torch.equal(a, c)
    # just below +180 and just above -180 are neighbours: they share the tile in most tilings
    near = coder(torch.tensor([[75.0, 75.0, 179.5], [75.0, 75.0, -179.5]]))
    assert (near[0] == near[1]).sum() >= 8
    # a non-wrapping dimension does not wrap: both ends differ in every tiling
    ends = coder(torch.tensor([[0.0, 75.0, 0.0], [150.0, 75.0, 0.0]]))
    assert (ends[0] != ends[1]).all()


def test_generalisation_decreases_with_distance():
    coder = _coder()
    base = coder(torch.tensor([[70.0, 70.0, 0.0]]))
    shared = [
        int((coder(torch.tensor([[70.0 + d, 70.0, 0.0]])) == base).sum()) for d in (0, 5, 15, 40)
    ]
    assert shared[0] == 9 and shared == sorted(shared, reverse=True) and shared[-1] == 0


def test_pure_function_matches_module_and_leading_dims():
    coder = _coder()
    x = torch.rand(2, 5, 3) * 100
    out = tile_indices(x, coder.low, coder.high, coder.resolution, coder.offsets, coder.wrap)
    assert out.shape == (2, 5, 9)
    assert torch.equal(out, coder(x))
    assert math.prod(coder.resolution.tolist()) == coder.tiles_per_tiling


def _point_major(x, coder):
    """The tile indices written point by point (``[..., T, D]`` cells, one ``where``)."""
    res = coder.resolution.to(x.dtype)
    shifted = ((x - coder.low) * (res / (coder.high - coder.low))).unsqueeze(-2) + coder.offsets
    cell = shifted.floor()
    cell = torch.where(coder.wrap, cell.remainder(res), torch.minimum(cell.clamp_min(0), res - 1))
    strides = torch.cumprod(torch.cat([res.new_ones(1), res.flip(0)[:-1]]), 0).flip(0)
    base = torch.arange(coder.n_tilings) * coder.tiles_per_tiling
    return (cell * strides).sum(-1).long() + base


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dimension_major_planes_give_the_point_major_indices(dtype):
    coder = TileCoder(
        [0.0, 0.0, -180.0, -15.0],
        [150.0, 150.0, 180.0, 15.0],
        [5, 5, 36, 5],
        9,
        wrap=[False, False, True, False],
    )  # the ship's low-level coder
    g = torch.Generator().manual_seed(0)
    span = torch.tensor([150.0, 150.0, 360.0, 30.0])
    x = (torch.rand(50_000, 4, generator=g) * 3 - 1) * span - torch.tensor([0, 0, 180.0, 15.0])
    edges = torch.randint(-40, 80, (20_000, 4), generator=g) / 40 * span  # on tile borders
    for points in (x, edges, x.view(10, -1, 4)):
        points = points.to(dtype)
        want = _point_major(points.float(), coder)
        assert torch.equal(coder(points), want)
        got = tile_indices(
            points, coder.low, coder.high, coder.resolution, coder.offsets, coder.wrap
        )
        assert torch.equal(got, _point_major(points, coder))


def test_bad_arguments():
    with pytest.raises(ValueError):
        TileCoder([0.0], [0.0], [3], 2)
    with pytest.raises(ValueError):
        TileCoder([0.0, 0.0], [1.0, 1.0], [3], 2)
    with pytest.raises(ValueError):
        TileCoder([0.0], [1.0], [3], 2, offsets=torch.zeros(3, 1))
