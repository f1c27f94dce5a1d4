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
    res = resolution.to(x.dtype)
    scale = res / (high - low)
    strides = _strides(resolution).to(x.dtype)
    base = torch.arange(offsets.shape[0], device=x.device) * int(torch.prod(resolution))
    return _active_tiles(x, low, scale, offsets, res, wrap, strides, base)


def _active_tiles(x, low, scale, offsets, res, wrap, strides, base) -> torch.Tensor:
    """``tile_indices`` on precomputed constants, in float (exact: indices stay below 2^24)."""
    shifted = ((x - low) * scale).unsqueeze(-2) + offsets  # [..., T, D] in tile widths
    cell = shifted.floor()
    cell = torch.where(wrap, cell.remainder(res), torch.minimum(cell.clamp_min(0), res - 1))
    return (cell * strides).sum(-1).long() + base  # row-major over the dimensions


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
        res = self.resolution.float()
        self.register_buffer("_res", res, persistent=False)
        self.register_buffer("_scale", res / (self.high - self.low), persistent=False)
        self.register_buffer("_strides", _strides(self.resolution).float(), persistent=False)
        base = torch.arange(n_tilings) * self.tiles_per_tiling
        self.register_buffer("_base", base, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Active tiles of points ``x [..., D]``: ``[..., T]`` long."""
        return _active_tiles(
            x.float(),
            self.low,
            self._scale,
            self.offsets,
            self._res,
            self.wrap,
            self._strides,
            self._base,
        )
