"""Policy heads of policy-gradient subtasks (Chapter 5) and their maths, batched.

A policy head (``hrl_torch.modules.heads.PolicyHead``) keeps, per learner of the population, one
block of the PG learner's flat parameters ``theta``; ``act`` chooses for a batch of rows and returns
the likelihood-ratio term ``grad mu(a|s) / mu(a|s)`` of Equation 5.3 as a sparse increment
``(index, score)`` into ``theta``: the eligibility ``z`` of Algorithm 3 (line 14) and the update
``theta += alpha * R * z`` (line 16) are ``index_add_`` of such pairs.

- ``SoftmaxPolicyHead``: one parameter per (state, child), as HPGRL on taxi-fuel-earlier (Section
  5.2.1): ``mu(a|s) = exp(theta[s, a]) / sum_b exp(theta[s, b])`` over available children; its
  likelihood ratio w.r.t. ``theta[s, :]`` is ``onehot(a) - mu(.|s)``.
- ``TileGaussianPolicyHead``: the low-level ship policy (Section 5.3): ``u ~ N(A, sigma^2)``
  with ``A = sum_i w_i phi_i / sum_i phi_i`` over CMAC tiles, action ``low + (high - low) *
  sigmoid(u)``. The likelihood ratio is taken for ``u``; the squashing is a fixed invertible map
  that does not depend on ``w``, so it cancels in ``grad mu / mu``:
  ``(u - A) / sigma^2 * phi_i / sum_j phi_j`` for each active tile ``i``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from hrl_torch.common.ops import one_hot_mask
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.modules.exploration import masked_argmax
from hrl_torch.modules.heads import PolicyChoice, PolicyHead, PolicyInput
from hrl_torch.modules.tiles import TileCoder

# -- tabular softmax


def softmax_probs(
    theta: torch.Tensor,
    learner: torch.Tensor,
    state: torch.Tensor,
    available: torch.Tensor | None = None,
) -> torch.Tensor:
    """Action probabilities ``[B, A]`` of ``theta [P, S, A]`` at rows ``(learner [B], state [B])``.

    Unavailable actions (``available [B, A]`` False) get probability 0.
    """
    logits = theta[learner, state]
    if available is not None:
        logits = logits.masked_fill(~available, -math.inf)
    return torch.softmax(logits, dim=-1)


def sample_categorical(probs: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Inverse-CDF sample ``[B]`` from ``probs [B, A]`` with uniforms ``u [B]`` in ``[0, 1)``.

    If rounding leaves ``u`` above the last cumulative probability, the last action with
    positive probability is taken, so an action of probability 0 is never returned.
    """
    cdf = probs.cumsum(-1)
    choice = (cdf <= u.unsqueeze(-1)).sum(-1)
    last_positive = probs.shape[-1] - 1 - (probs > 0).flip(-1).long().argmax(-1)
    return torch.minimum(choice, last_positive)


def softmax_log_prob(probs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """``log mu(a|s)`` ``[B]`` of the actions ``[B]`` under ``probs [B, A]``."""
    return probs.gather(-1, action.unsqueeze(-1)).squeeze(-1).log()


def softmax_score(probs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """``grad_theta[s, :] mu(a|s) / mu(a|s) = onehot(a) - mu(.|s)``: ``[B, A]``."""
    onehot = one_hot_mask(action, probs.shape[-1]).to(probs.dtype)
    return onehot - probs


# -- tile-coded Gaussian


def squash(u: torch.Tensor, low: float, high: float) -> torch.Tensor:
    """``low + (high - low) * sigmoid(u)``: a real number into the action range."""
    return low + (high - low) * torch.sigmoid(u)


def unsquash(action: torch.Tensor, low: float, high: float) -> torch.Tensor:
    """Inverse of ``squash`` (``action`` strictly inside ``(low, high)``)."""
    return torch.logit((action - low) / (high - low))


def gaussian_log_prob(u: torch.Tensor, mean: torch.Tensor, sigma: float) -> torch.Tensor:
    """``log N(u; mean, sigma^2)`` elementwise."""
    return -0.5 * ((u - mean) / sigma) ** 2 - math.log(sigma) - 0.5 * math.log(2 * math.pi)


def gaussian_tile_score(
    u: torch.Tensor, mean: torch.Tensor, n_tiles: int, sigma: float
) -> torch.Tensor:
    """``(u - A) / sigma^2 * phi_i / sum_j phi_j`` for each of the ``n_tiles`` active tiles.

    Args:
        u: sampled pre-squash values ``[B]``.
        mean: ``A`` ``[B]``.
        n_tiles: active tiles per row ``T``.
        sigma: standard deviation.

    Returns:
        ``[B, T]`` (the same value for every active tile).
    """
    per_tile = (u - mean) / (sigma**2 * n_tiles)
    return per_tile.unsqueeze(-1).expand(*per_tile.shape, n_tiles)


def box_muller(u1: torch.Tensor, u2: torch.Tensor) -> torch.Tensor:
    """Standard normals from two uniforms in ``[0, 1)`` (same shapes)."""
    return torch.sqrt(-2.0 * torch.log(u1.clamp_min(1e-7))) * torch.cos(2.0 * math.pi * u2)


def normals(u: torch.Tensor, d: int) -> torch.Tensor:
    """``d`` independent standard normals per row ``[n, d]`` from uniforms ``u [n, W]``.

    Box-Muller on the pairs ``(u[:, 1], u[:, 2])``, ``(u[:, 3], u[:, 4])``, ...: each pair
    gives two normals (cosine and sine), so ``W >= 1 + 2 ceil(d / 2)`` (column 0 is left to
    a categorical choice). The first is ``box_muller(u[:, 1], u[:, 2])``.
    """
    m = (d + 1) // 2
    if u.shape[1] < 1 + 2 * m:
        raise ValueError(f"{d} normals need {1 + 2 * m} uniforms per row, got {u.shape[1]}")
    radius = torch.sqrt(-2.0 * torch.log(u[:, 1 : 2 * m : 2].clamp_min(1e-7)))
    angle = 2.0 * math.pi * u[:, 2 : 2 * m + 1 : 2]
    pairs = torch.stack([radius * torch.cos(angle), radius * torch.sin(angle)], -1)
    return pairs.reshape(u.shape[0], 2 * m)[:, :d]


class ActionRange:
    """Mixin of a continuous head: its action range, given or the env's ``action_bounds``.

    ``low``/``high``: numbers for one action entry, tuples of ``action_dim`` numbers for more
    (``None`` until given: the trainer sets the env's, ``use_action_bounds``).
    """

    low = high = None
    action_dim = 1
    #: how a user gives the range (the errors name it)
    range_hint = "PGConfig(action_low=..., action_high=...)"

    def init_range(self, low, high, old_default: tuple[float, float] | None = None) -> None:
        """Take ``(low, high)`` if given; ``old_default``: the range used before, when none was."""
        if (low is None) != (high is None):
            raise ValueError(
                f"Gaussian head {self.name!r}: give both ends of the action range or none"
            )
        #: the silent default of an older version this head would have had (a warning's)
        self.old_default = old_default if low is None else None
        if low is not None:
            self.set_range(low, high)

    def set_range(self, low: float | Sequence[float], high: float | Sequence[float]) -> None:
        """The action range ``[low, high]`` that ``squash`` maps into (``low < high``).

        Numbers, or one per action entry (a number serves every entry).
        """
        d = self.action_dim
        lo = [float(v) for v in low] if isinstance(low, Sequence) else [float(low)] * d
        hi = [float(v) for v in high] if isinstance(high, Sequence) else [float(high)] * d
        if len(lo) != d or len(hi) != d:
            raise ValueError(
                f"Gaussian head {self.name!r} acts with {d} numbers: the action range has "
                f"{len(lo)} and {len(hi)} ends"
            )
        if not all(a < b for a, b in zip(lo, hi, strict=True)):
            raise ValueError(f"Gaussian head {self.name!r}: action range needs low < high")
        if d == 1:
            self.low, self.high = lo[0], hi[0]
            return
        self.low, self.high = tuple(lo), tuple(hi)
        device = next(iter(self.buffers()), torch.empty(0)).device
        for name, ends in (("action_lo", lo), ("action_hi", hi)):
            self.register_buffer(name, torch.tensor(ends, device=device), persistent=False)

    def range(self) -> tuple:
        """``(low, high)``; a clear error while neither the head nor the env gave one."""
        if self.low is None:
            old = ""
            if getattr(self, "old_default", None) is not None:
                old = f" (before 0.2.1 it defaulted to {self.old_default})"
            raise ValueError(
                f"Gaussian head {self.name!r} has no action range{old}: give "
                f"{self.range_hint} or train on an env with action_bounds"
            )
        return self.low, self.high

    def squash(self, u: torch.Tensor) -> torch.Tensor:
        """``u [n]`` (or ``[n, action_dim]``) into the range, entry by entry (``squash``)."""
        low, high = self.range()
        if self.action_dim == 1:
            return squash(u, low, high)
        return self.action_lo + (self.action_hi - self.action_lo) * torch.sigmoid(u)


# -- heads


class SoftmaxPolicyHead(PolicyHead):
    """Softmax over a node's available children, one parameter per (abstract state, child).

    The block is ``[n_states, stride]`` with ``stride`` the graph's ``max_children``, so the
    softmax heads of every PG node share one ``act`` call.

    Args:
        name: the head's name (its subtask or group).
        n_states: abstract states of the node(s).
        n_children: children of the node(s).
        stride: columns of the block (``graph.max_children``).
    """

    def __init__(self, name: str, n_states: int, n_children: int, stride: int) -> None:
        super().__init__(name, n_states, stride)
        self.n_children = int(n_children)
        self.width = int(stride)

    def batch_key(self) -> object:
        """Every softmax head of a learner shares one call."""
        return (SoftmaxPolicyHead, self.n_cols)

    def check(self, graph: TaskGraph, node: int) -> None:
        """The node's states and children must match the head's block."""
        x = graph.nodes[node]
        if (x.n_states, len(x.children_names)) != (self.n_states, self.n_children):
            raise GraphError(f"nodes of PG group {self.name!r} differ in shape: {x.name!r}")

    def act(self, theta: torch.Tensor, inp: PolicyInput, greedy: bool) -> PolicyChoice:
        """Sample from (or take the mode of) ``mu(.|s)``; score ``onehot(a) - mu(.|s)``."""
        ok = inp.available
        cols = torch.arange(ok.shape[1], device=ok.device)
        index = inp.base[:, None] + inp.state[:, None] * self.n_cols + cols
        index = torch.where(ok, index, theta.numel() - 1)
        logits = theta.index_select(0, index.reshape(-1)).view(index.shape)
        logits = logits.masked_fill(~ok, -math.inf)
        logits = torch.where(ok.any(-1, keepdim=True), logits, 0.0)
        probs = torch.softmax(logits, -1)
        best = masked_argmax(logits, ok)
        pick = best if greedy else sample_categorical(probs, inp.u[:, 0])
        score = torch.where(ok, softmax_score(probs, pick), 0.0)
        return PolicyChoice(pick, pick == best, None, index, score)


class TileGaussianPolicyHead(ActionRange, PolicyHead):
    """Gaussian over tile-coded features, squashed into ``[low, high]``: ``w [n_tiles]``.

    Args:
        name: the head's name (its subtask or group).
        coder: the tile coder of the node's features.
        sigma: standard deviation of ``u`` (1 in the text's density).
        action_low: lower end of the action range; ``None``: the env's ``action_bounds``, set
            by the trainer at its start (``set_range``; acting without one is an error).
        action_high: upper end of the action range (``None`` with ``action_low``).
    """

    continuous = True

    def __init__(
        self,
        name: str,
        coder: TileCoder,
        sigma: float = 1.0,
        action_low: float | None = None,
        action_high: float | None = None,
    ) -> None:
        if sigma <= 0:
            raise ValueError(f"sigma must be positive, got {sigma}")
        super().__init__(name, 1, coder.n_features)
        self.coder = coder
        self.sigma = float(sigma)
        self.init_range(action_low, action_high)
        self.width = coder.n_tilings

    def batch_key(self) -> object:
        """Gaussian heads over one coder with one sigma and range share one call."""
        return (TileGaussianPolicyHead, id(self.coder), self.sigma, self.low, self.high)

    def check(self, graph: TaskGraph, node: int) -> None:
        """The node needs one continuous primitive child and enough features."""
        x = graph.nodes[node]
        children = [graph.node(c) for c in x.children_names]
        if len(children) != 1 or not children[0].is_primitive or not children[0].action_dim:
            raise GraphError(f"PG node {x.name!r}: a Gaussian head needs one continuous child")
        dims = self.coder.resolution.numel()
        if x.n_features < dims:
            raise GraphError(
                f"PG node {x.name!r} needs >= {dims} features for the tile coder, "
                f"has {x.n_features}"
            )

    def mean(self, theta: torch.Tensor, base: torch.Tensor, features: torch.Tensor):
        """``(active tiles [n, T] as flat indices, A [n])`` at the rows' features."""
        dims = self.coder.resolution.numel()
        tiles = self.coder(features[:, :dims]) + base[:, None]
        return tiles, theta.index_select(0, tiles.reshape(-1)).view(tiles.shape).mean(-1)

    def act(self, theta: torch.Tensor, inp: PolicyInput, greedy: bool) -> PolicyChoice:
        """``u = A + sigma z`` (or ``A``), action ``squash(u)``; score per active tile."""
        tiles, mean = self.mean(theta, inp.base, inp.features)
        pre = mean if greedy else mean + self.sigma * box_muller(inp.u[:, 1], inp.u[:, 2])
        score = gaussian_tile_score(pre, mean, tiles.shape[-1], self.sigma)
        flag = torch.full_like(inp.base, greedy, dtype=torch.bool)
        child = torch.zeros_like(inp.base)
        return PolicyChoice(child, flag, squash(pre, *self.range()), tiles, score)
