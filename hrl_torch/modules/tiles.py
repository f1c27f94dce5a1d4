"""CMAC tile coding (Albus, 1975; Sutton & Barto, 2018, Section 9.5.4), batched.

A tile coder covers a box ``[low, high]`` (one interval per dimension) with ``T`` tilings.
Each tiling is a grid of exactly ``prod(resolution)`` tiles; tiling ``t`` is displaced by
``offsets[t, d]`` tile widths along dimension ``d``. A point activates one tile per tiling, so
its features are ``T`` flat indices into ``T * prod(resolution)`` weights (tiling ``t`` owns the
block ``[t * prod(resolution), (t + 1) * prod(resolution))``). The dissertation's low-level ship
subtasks use 9 tilings of ``5 x 5 x 36 x 5``: 9 x 4,500 = 40,500 weights (Section 5.3).

Displacement scheme (``asymmetric_offsets``): tiling ``t`` is shifted by ``t * k_d / T`` tile
widths (modulo one tile) along dimension ``d``, with ``k = (1, 3, 5, 7, ...)``, the asymmetric
displacement vector Sutton & Barto recommend (uniform ``k = (1, 1, ...)`` puts every tiling on a
diagonal). Odd numbers sharing a factor with ``T`` are skipped so that each dimension gets ``T``
distinct offsets (for ``T = 9``: ``k = (1, 5, 7, 11)``); for ``T`` a power of two this is
exactly Sutton & Barto's vector.

Edges. On a non-wrapping dimension the shifted grid is clipped to the box: the first tile of a
tiling covers ``[0, 1 - offset)`` tile widths, the last one ``[res - 1 - offset, res]``, and
points outside the box clamp to the edge tiles. On a wrapping dimension (an angle) tile indices
are taken modulo the resolution, so ``high`` and ``low`` fall in the same tile.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn


def asymmetric_offsets(n_tilings: int, n_dims: int) -> torch.Tensor:
    """Offsets of each tiling in tile widths, ``[n_tilings, n_dims]`` in ``[0, 1)``.

    Tiling ``t`` is displaced by ``(t * k_d / n_tilings) mod 1`` with ``k`` the first ``n_dims``
    odd numbers coprime with ``n_tilings`` (see the module docstring).
    """
    k: list[int] = []
    odd = 1
    while len(k) < n_dims:
        if math.gcd(odd, n_tilings) == 1:
            k.append(odd)
        odd += 2
    t = torch.arange(n_tilings, dtype=torch.float64)[:, None]
    step = torch.tensor(k, dtype=torch.float64)[None, :]
    return torch.remainder(t * step / n_tilings, 1.0).float()


def tile_indices(
    x: torch.Tensor,
    low: torch.Tensor,
    high: torch.Tensor,
    resolution: torch.Tensor,
    offsets: torch.Tensor,
    wrap: torch.Tensor,
) -> torch.Tensor:
    """Flat indices of the active tiles.

    Args:
        x: points ``[..., D]``.
        low: lower corner of the box ``[D]``.
        high: upper corner of the box ``[D]``.
        resolution: tiles per dimension ``[D]`` (long).
        offsets: displacement of each tiling in tile widths ``[T, D]``, in ``[0, 1)``.
        wrap: ``[D]`` bool, dimensions whose tiles wrap around (angles).

    Returns:
        ``[..., T]`` long indices in ``[0, T * prod(resolution))``, one per tiling; tiling ``t``
        gives an index in ``[t * prod(resolution), (t + 1) * prod(resolution))``.
    """
    return _active_tiles(x, **_layout(low, high, resolution, offsets, wrap, x.dtype))


def _layout(low, high, resolution, offsets, wrap, dtype: torch.dtype) -> dict:
    """The constants of ``_active_tiles``, shaped for its dimension-major planes ``[D, T, n]``."""
    res = resolution.to(dtype)
    n_tilings, n_dims = offsets.shape
    column = (n_dims, 1, 1)
    return {
        "low": low[:, None],
        "scale": (res / (high - low))[:, None],
        "offsets": offsets.t().reshape(n_dims, n_tilings, 1),
        "max_cell": (res - 1).view(column),
        "strides": _strides(resolution).to(dtype).view(column),
        "base": torch.arange(n_tilings, device=resolution.device) * int(torch.prod(resolution)),
        "wrap_dims": [(d, float(res[d])) for d in range(n_dims) if bool(wrap[d])],
    }


def _active_tiles(x, low, scale, offsets, max_cell, strides, base, wrap_dims) -> torch.Tensor:
    """``tile_indices`` on the constants of ``_layout``, in float (exact: indices stay below 2^24).

    Dimension-major: the cells are planes ``[D, T, n]``, so every op runs along the ``n``
    points (broadcasting over a short last dimension is slow on CPU), and a wrapping
    dimension's ``remainder`` only touches its own plane. Its cells are then in
    ``[0, res)`` already, so clipping every plane to ``[0, res - 1]`` leaves them alone.
    """
    lead, n_dims = x.shape[:-1], x.shape[-1]
    points = (x if x.dim() == 2 else x.reshape(-1, n_dims)).t().contiguous()  # [D, n]
    cell = (((points - low) * scale).unsqueeze(1) + offsets).floor_()  # tile widths, floored
    for d, res in wrap_dims:
        cell[d].remainder_(res)
    torch.minimum(cell.clamp_min_(0), max_cell, out=cell)
    flat = cell.mul_(strides).sum(0)  # [T, n]: row-major over the dimensions
    tiles = flat.t().to(torch.long, memory_format=torch.contiguous_format).add_(base)
    return tiles if x.dim() == 2 else tiles.view(*lead, base.shape[0])


def _strides(resolution: torch.Tensor) -> torch.Tensor:
    """Row-major strides of a grid with ``resolution`` cells per dimension."""
    after = torch.cumprod(resolution.flip(0), 0).flip(0)  # prod(resolution[d:])
    return torch.cat([after[1:], after.new_ones(1)])


class TileCoder(nn.Module):
    """CMAC over a box: maps points ``[..., D]`` to active tile indices ``[..., T]``.

    Args:
        low: lower corner of the box, one value per dimension.
        high: upper corner of the box.
        resolution: tiles per dimension in each tiling.
        n_tilings: number of tilings ``T``.
        wrap: per dimension, whether it wraps around (default: none).
        offsets: ``[T, D]`` displacements in tile widths (default: ``asymmetric_offsets``).
    """

    def __init__(
        self,
        low: Sequence[float],
        high: Sequence[float],
        resolution: Sequence[int],
        n_tilings: int,
        wrap: Sequence[bool] | None = None,
        offsets: torch.Tensor | None = None,
    ) -> None:
        super().__init__()
        n_dims = len(resolution)
        if not len(low) == len(high) == n_dims:
            raise ValueError(f"low, high and resolution need one entry per dimension ({n_dims})")
        if any(h <= lo for lo, h in zip(low, high, strict=True)):
            raise ValueError(f"need low < high in every dimension, got {low} and {high}")
        if min(resolution) < 1 or n_tilings < 1:
            raise ValueError("resolution and n_tilings must be >= 1")
        wrap = [False] * n_dims if wrap is None else list(wrap)
        if offsets is None:
            offsets = asymmetric_offsets(n_tilings, n_dims)
        if offsets.shape != (n_tilings, n_dims):
            raise ValueError(f"offsets must be [{n_tilings}, {n_dims}], got {tuple(offsets.shape)}")
        self.register_buffer("low", torch.tensor(low, dtype=torch.float32))
        self.register_buffer("high", torch.tensor(high, dtype=torch.float32))
        self.register_buffer("resolution", torch.tensor(resolution, dtype=torch.long))
        self.register_buffer("wrap", torch.tensor(wrap, dtype=torch.bool))
        self.register_buffer("offsets", offsets.float())
        self.n_tilings = n_tilings
        self.tiles_per_tiling = math.prod(resolution)
        self.n_features = n_tilings * self.tiles_per_tiling
        if self.tiles_per_tiling >= 2**24:
            raise ValueError("a tiling of 2^24 tiles or more is not supported (float indices)")
        layout = _layout(
            self.low, self.high, self.resolution, self.offsets, self.wrap, torch.float32
        )
        self._wrap_dims = layout.pop("wrap_dims")
        for name, value in layout.items():
            self.register_buffer(f"_{name}", value, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Active tiles of points ``x [..., D]``: ``[..., T]`` long."""
        return _active_tiles(
            x.float(),
            self._low,
            self._scale,
            self._offsets,
            self._max_cell,
            self._strides,
            self._base,
            self._wrap_dims,
        )
