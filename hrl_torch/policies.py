"""Parameterised stochastic policies for policy-gradient subtasks (Chapter 5), batched.

Every parameter tensor has a leading population dimension ``P`` (independent learners); row
``b`` of a batch uses the parameters of learner ``learner[b]``. Each policy gives its action
probabilities (or density), samples from uniforms / normals drawn with a ``BatchRNG``, and
returns the likelihood-ratio term ``grad mu(a|s) / mu(a|s)`` of Equation 5.3 as a sparse
increment ``(index, value)`` into its flattened parameters: ``z.view(-1).index_add_(0,
index.flatten(), value.flatten())`` accumulates the eligibility ``z``, and the update
``theta += alpha * R * z`` of Algorithm 3 (line 16) is a dense or sparse add of the same kind.

- ``TabularSoftmaxPolicy``: one parameter per (state, action) pair, as HPGRL on taxi-fuel
  (Section 5.2.1): ``mu(a|s) = exp(theta[s, a]) / sum_b exp(theta[s, b])`` over available
  actions; its likelihood ratio w.r.t. ``theta[s, :]`` is ``onehot(a) - mu(.|s)``.
- ``TileGaussianPolicy``: the low-level ship policy (Section 5.3): ``u ~ N(A, sigma^2)`` with
  ``A = sum_i w_i phi_i / sum_i phi_i`` over CMAC tiles, action ``low + (high - low) *
  sigmoid(u)``. The likelihood ratio is taken for ``u``; the squashing is a fixed invertible map
  that does not depend on ``w``, so it cancels in ``grad mu / mu``:
  ``(u - A) / sigma^2 * phi_i / sum_j phi_j`` for each active tile ``i``.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from hrl_torch.tiles import TileCoder

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
    onehot = torch.nn.functional.one_hot(action, probs.shape[-1]).to(probs.dtype)
    return onehot - probs


def tabular_row_index(
    learner: torch.Tensor, state: torch.Tensor, n_states: int, n_actions: int
) -> torch.Tensor:
    """Flat indices ``[B, A]`` of ``theta[learner, state, :]`` in ``theta.view(-1)``."""
    row = (learner * n_states + state) * n_actions
    return row.unsqueeze(-1) + torch.arange(n_actions, device=row.device)


class TabularSoftmaxPolicy(nn.Module):
    """Softmax policy with one parameter per (state, action): ``theta [P, S, A]`` (a buffer).

    Args:
        n_learners: population size ``P``.
        n_states: number of (abstract) states ``S``.
        n_actions: number of actions ``A``.
        init: initial value of every parameter (0: uniform policy).
    """

    def __init__(self, n_learners: int, n_states: int, n_actions: int, init: float = 0.0) -> None:
        super().__init__()
        self.n_states = n_states
        self.n_actions = n_actions
        self.register_buffer("theta", torch.full((n_learners, n_states, n_actions), float(init)))

    def probs(
        self, learner: torch.Tensor, state: torch.Tensor, available: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``mu(.|s)`` ``[B, A]``."""
        return softmax_probs(self.theta, learner, state, available)

    def sample(
        self,
        learner: torch.Tensor,
        state: torch.Tensor,
        u: torch.Tensor,
        available: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Actions ``[B]`` drawn with uniforms ``u [B]`` (e.g. ``rng.uniform()``)."""
        return sample_categorical(self.probs(learner, state, available), u)

    def log_prob(
        self,
        learner: torch.Tensor,
        state: torch.Tensor,
        action: torch.Tensor,
        available: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``log mu(a|s)`` ``[B]``."""
        return softmax_log_prob(self.probs(learner, state, available), action)

    def score(
        self,
        learner: torch.Tensor,
        state: torch.Tensor,
        action: torch.Tensor,
        available: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Likelihood ratio as ``(index [B, A] into theta.view(-1), value [B, A])``."""
        value = softmax_score(self.probs(learner, state, available), action)
        return tabular_row_index(learner, state, self.n_states, self.n_actions), value


# -- tile-coded Gaussian


def tile_mean(w: torch.Tensor, learner: torch.Tensor, tiles: torch.Tensor) -> torch.Tensor:
    """``A = sum_i w_i phi_i / sum_i phi_i`` ``[B]`` for binary features.

    Args:
        w: weights ``[P, F]``.
        learner: ``[B]``.
        tiles: active tile indices ``[B, T]`` (one per tiling, so ``sum_i phi_i = T``).
    """
    return w[learner.unsqueeze(-1), tiles].mean(-1)


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


class TileGaussianPolicy(nn.Module):
    """Gaussian policy over tile-coded states, squashed into ``[low, high]``: ``w [P, F]``.

    Args:
        n_learners: population size ``P``.
        coder: the tile coder of the (local) state; ``F = coder.n_features``.
        action_low: lower end of the action range (-15 deg/s for the ship).
        action_high: upper end of the action range.
        sigma: standard deviation of ``u`` (1 in the text's density).
        init: initial weight (0: mean action at the middle of the range).
    """

    def __init__(
        self,
        n_learners: int,
        coder: TileCoder,
        action_low: float = -15.0,
        action_high: float = 15.0,
        sigma: float = 1.0,
        init: float = 0.0,
    ) -> None:
        super().__init__()
        if sigma <= 0:
            raise ValueError(f"sigma must be positive, got {sigma}")
        self.coder = coder
        self.action_low = float(action_low)
        self.action_high = float(action_high)
        self.sigma = float(sigma)
        self.n_features = coder.n_features
        self.register_buffer("w", torch.full((n_learners, coder.n_features), float(init)))

    def tiles(self, obs: torch.Tensor) -> torch.Tensor:
        """Active tiles ``[B, T]`` of states ``obs [B, D]``."""
        return self.coder(obs)

    def mean(self, learner: torch.Tensor, tiles: torch.Tensor) -> torch.Tensor:
        """``A`` ``[B]``."""
        return tile_mean(self.w, learner, tiles)

    def sample(
        self, learner: torch.Tensor, tiles: torch.Tensor, noise: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(action [B], u [B])`` from standard normals ``noise [B]`` (e.g. ``rng.normal()``).

        ``u = A + sigma * noise`` is what ``score`` needs; ``action = squash(u)``.
        """
        u = self.mean(learner, tiles) + self.sigma * noise
        return squash(u, self.action_low, self.action_high), u

    def log_prob(self, learner: torch.Tensor, tiles: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """``log N(u; A, sigma^2)`` ``[B]`` (density of the pre-squash value)."""
        return gaussian_log_prob(u, self.mean(learner, tiles), self.sigma)

    def score(
        self, learner: torch.Tensor, tiles: torch.Tensor, u: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Likelihood ratio as ``(index [B, T] into w.view(-1), value [B, T])``."""
        value = gaussian_tile_score(u, self.mean(learner, tiles), tiles.shape[-1], self.sigma)
        index = learner.unsqueeze(-1) * self.n_features + tiles
        return index, value
