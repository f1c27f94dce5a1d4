"""A Gaussian policy head whose mean is an MLP and whose score comes from autograd.

``MLPGaussianPolicyHead`` plugs into the policy-gradient learners like the tile-coded head
(``hrl_torch.modules.policies.TileGaussianPolicyHead``): HPGRL (Algorithm 3), flat PGRL and the
hybrid's PG nodes route a node to it, it chooses for the node's rows and returns the
likelihood-ratio term of each choice (Equation 5.3). Where the tile-coded head writes
``grad log mu`` by hand (``gaussian_tile_score``), this one asks autograd for it:

    u = A_theta(x) + sigma z,   action = squash(u),
    score = d/dtheta log N(u; A_theta(x), sigma^2) = (u - A) / sigma^2 * dA/dtheta

Its parameters are the head's block of the learner's flat ``theta`` (``[P, 1, K]``, ``K`` every
weight of the MLP). Each row reads its own learner's copy, ``theta[base + 0..K-1]`` ``[n, K]``,
as a leaf of its own, so the gradient of ``sum_n log mu_n`` with respect to it is every row's
own score at once (no per-sample loop, no ``vmap``), with no value read back to the host.

The inputs are the node's features, either scaled into ``[-1, 1]`` (``low``/``high``) or, with a
``coder``, as dense tile indicators ``phi_i(x) / T`` (a linear head, ``hidden=()`` and
``bias=False``, is then the tile-coded head, with autograd: ``tests/test_neural_policies.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.modules.heads import PolicyChoice, PolicyHead, PolicyInput
from hrl_torch.modules.policies import box_muller, squash
from hrl_torch.modules.tables import TableBank
from hrl_torch.modules.tiles import TileCoder


class MLPGaussianPolicyHead(PolicyHead):
    """Gaussian over ``A_theta(x)``, an MLP of the node's features, squashed into the range.

    Args:
        name: the head's name (its subtask or group).
        n_inputs: features the MLP reads (the first ``n_inputs`` of the node's).
        hidden: hidden widths (``tanh``; a number: one layer); ``()`` for a linear mean.
        sigma: standard deviation of ``u``.
        action_low: lower end of the action range.
        action_high: upper end of the action range.
        low: per feature, the value mapped to -1 (default: no scaling).
        high: per feature, the value mapped to +1.
        coder: instead of scaling, dense tile indicators of the features (``phi / T``).
        bias: the layers have biases.
        init_seed: seed of the hidden layers' initial weights (the output layer starts at 0:
            the mean starts at 0, every learner from the same weights).
    """

    continuous = True

    def __init__(
        self,
        name: str,
        n_inputs: int,
        hidden: int | Sequence[int] = (32,),
        sigma: float = 1.0,
        action_low: float = -15.0,
        action_high: float = 15.0,
        low: Sequence[float] | None = None,
        high: Sequence[float] | None = None,
        coder: TileCoder | None = None,
        bias: bool = True,
        init_seed: int = 0,
    ) -> None:
        if sigma <= 0:
            raise ValueError(f"sigma must be positive, got {sigma}")
        if (low is None) != (high is None) or (low is not None and coder is not None):
            raise ValueError("give low and high together, or a coder, or neither")
        hidden = (hidden,) if isinstance(hidden, int) else tuple(hidden)
        width_in = coder.n_features if coder is not None else int(n_inputs)
        widths = [width_in, *(int(h) for h in hidden), 1]
        self.shapes = [(a, b) for a, b in zip(widths[:-1], widths[1:], strict=True)]
        n_params = sum(a * b + (b if bias else 0) for a, b in self.shapes)
        super().__init__(name, 1, n_params)
        self.width = n_params
        self.n_inputs, self.bias = int(n_inputs), bool(bias)
        self.coder = coder
        self.sigma, self.low, self.high = float(sigma), float(action_low), float(action_high)
        if low is not None:
            lo, hi = torch.tensor(low, dtype=torch.float32), torch.tensor(high, dtype=torch.float32)
            if lo.shape != (self.n_inputs,) or hi.shape != lo.shape or not bool((hi > lo).all()):
                raise ValueError(f"low and high need {self.n_inputs} values each with low < high")
            self.register_buffer("x_mid", (hi + lo) / 2, persistent=False)
            self.register_buffer("x_half", (hi - lo) / 2, persistent=False)
        else:
            self.x_mid = self.x_half = None
        gen = torch.Generator().manual_seed(int(init_seed))
        parts = []
        for k, (a, b) in enumerate(self.shapes):
            last = k == len(self.shapes) - 1
            bound = 0.0 if last else math.sqrt(6.0 / (a + b))  # (Glorot-uniform for tanh)
            parts.append(((torch.rand(a * b, generator=gen) * 2 - 1) * bound).view(-1))
            if bias:
                parts.append(torch.zeros(b))
        self.register_buffer("theta0", torch.cat(parts), persistent=False)

    def bind(self, bank: TableBank, table: int) -> None:
        """Store the parameters in ``bank``'s block ``table``, starting at the initial weights."""
        super().bind(bank, table)
        with torch.no_grad():
            bank.block(table).copy_(self.theta0.to(bank.store.device).view(1, 1, -1))

    def check(self, graph: TaskGraph, node: int) -> None:
        """The node needs one continuous primitive child and enough features."""
        x = graph.nodes[node]
        children = [graph.node(c) for c in x.children_names]
        if len(children) != 1 or not children[0].is_primitive or not children[0].action_dim:
            raise GraphError(f"PG node {x.name!r}: a Gaussian head needs one continuous child")
        dims = self.coder.resolution.numel() if self.coder is not None else self.n_inputs
        if x.n_features < dims:
            raise GraphError(f"PG node {x.name!r} needs >= {dims} features, has {x.n_features}")

    def inputs(self, features: torch.Tensor) -> torch.Tensor:
        """The MLP's inputs ``[n, F]`` from the node's features."""
        if self.coder is not None:
            tiles = self.coder(features[:, : self.coder.resolution.numel()])
            phi = torch.zeros(tiles.shape[0], self.coder.n_features, device=features.device)
            return phi.scatter_add_(
                1, tiles, torch.full_like(phi[:, : tiles.shape[1]], 1 / tiles.shape[1])
            )
        x = features[:, : self.n_inputs]
        return x if self.x_mid is None else (x - self.x_mid) / self.x_half

    def mean(self, params: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """``A_theta(x)`` ``[n]`` for per-row parameters ``params [n, K]`` and inputs ``x``."""
        at, h = 0, x[:, None, :]
        for k, (a, b) in enumerate(self.shapes):
            w = params[:, at : at + a * b].view(-1, a, b)
            at += a * b
            h = torch.bmm(h, w)
            if self.bias:
                h = h + params[:, None, at : at + b]
                at += b
            if k < len(self.shapes) - 1:
                h = torch.tanh(h)
        return h[:, 0, 0]

    def act(self, theta: torch.Tensor, inp: PolicyInput, greedy: bool) -> PolicyChoice:
        """``u = A + sigma z`` (or ``A``), action ``squash(u)``; the score by autograd."""
        index = inp.base[:, None] + torch.arange(self.width, device=inp.base.device)
        x = self.inputs(inp.features)
        with torch.enable_grad():
            params = theta.index_select(0, index.reshape(-1)).view(index.shape)
            params = params.detach().requires_grad_(True)
            mean = self.mean(params, x)
            noise = 0.0 if greedy else self.sigma * box_muller(inp.u[:, 1], inp.u[:, 2])
            pre = mean.detach() + noise
            log_mu = -0.5 * ((pre - mean) / self.sigma) ** 2  # (+ a constant in theta)
            (score,) = torch.autograd.grad(log_mu.sum(), params)
        flag = torch.full_like(inp.base, greedy, dtype=torch.bool)
        child = torch.zeros_like(inp.base)
        return PolicyChoice(child, flag, squash(pre, self.low, self.high), index, score)
