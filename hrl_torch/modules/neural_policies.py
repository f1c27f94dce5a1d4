"""Policy heads whose policy is an MLP and whose score comes from autograd.

The heads plug into the policy-gradient learners like the tile-coded and softmax heads
(``hrl_torch.modules.policies``): HPGRL (Algorithm 3), flat PGRL and the hybrid's PG nodes route a
node to them, they choose for the node's rows and return the likelihood-ratio term of each
choice (Equation 5.3). Where the table and tile heads write ``grad log mu`` by hand, these ask
autograd for it, from the log-probability of a ``torch.distributions`` distribution:

- ``MLPGaussianPolicyHead``: ``u = A_theta(x) + sigma z`` over an action vector of
  ``action_dim`` entries (diagonal covariance ``sigma^2 I``), ``action = squash(u)`` per entry;
  ``score = d/dtheta log N(u; A_theta(x), sigma^2 I)``.
- ``MLPCategoricalPolicyHead``: a softmax over the node's available children of the logits
  ``L_theta(x)``; ``score = d/dtheta log Categorical(a; L_theta(x))``.

A head's parameters are its block of the learner's flat ``theta`` (``[P, 1, K]``, ``K`` every
weight of the MLP). Each row reads its own learner's copy, ``theta[base + 0..K-1]`` ``[n, K]``,
as a leaf of its own, so the gradient of ``sum_n log mu_n`` with respect to it is every row's
own score at once (no per-sample loop, no ``vmap``), with no value read back to the host.
Sampling uses the row's own uniforms (Box-Muller, inverse CDF), not torch's global generator:
a row's choice depends on its stream alone, as with every other head.

The inputs (``MLPInputs``) are the node's features, scaled into ``[-1, 1]`` (``low``/``high``),
an angle as its sine and cosine (``wrap``), or dense tile indicators ``phi_i(x) / T``
(``coder``: a linear Gaussian head, ``hidden=()`` and ``bias=False``, is then the tile-coded
head, with autograd: ``tests/test_neural_policies.py``), or a one-hot of the node's abstract
state (``n_states``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch.distributions import Categorical, Normal

from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.modules.exploration import masked_argmax
from hrl_torch.modules.heads import PolicyChoice, PolicyHead, PolicyInput
from hrl_torch.modules.policies import ActionRange, box_muller, normals, sample_categorical
from hrl_torch.modules.tables import TableBank
from hrl_torch.modules.tiles import TileCoder

__all__ = ["MLPCategoricalPolicyHead", "MLPGaussianPolicyHead", "MLPPolicyHead"]

#: the range ``MLPGaussianPolicyHead`` used when given none, before 0.2.1 (the ship's rudder)
_OLD_RANGE = (-15.0, 15.0)


def _input_width(n_inputs: int, wrap, coder: TileCoder | None, n_states: int | None) -> int:
    """The MLP's input width for the encoding."""
    if coder is not None:
        return coder.n_features
    if n_states is not None:
        return n_states
    if wrap is not None and len(wrap) != n_inputs:
        raise ValueError(f"wrap needs {n_inputs} flags, got {len(wrap)}")
    return n_inputs + (sum(bool(w) for w in wrap) if wrap is not None else 0)


def _initial_weights(shapes, bias: bool, seed: int) -> torch.Tensor:
    """Glorot-uniform hidden layers (for ``tanh``), a zero output layer, zero biases."""
    gen = torch.Generator().manual_seed(seed)
    parts = []
    for k, (a, b) in enumerate(shapes):
        bound = 0.0 if k == len(shapes) - 1 else math.sqrt(6.0 / (a + b))
        parts.append(((torch.rand(a * b, generator=gen) * 2 - 1) * bound).view(-1))
        if bias:
            parts.append(torch.zeros(b))
    return torch.cat(parts)


class MLPPolicyHead(PolicyHead):
    """Base of the MLP heads: the inputs, the weights' layout in ``theta`` and the forward.

    Args:
        name: the head's name (its subtask or group).
        n_inputs: features the MLP reads (the first ``n_inputs`` of the node's).
        n_outputs: the last layer's width.
        hidden: hidden widths (``tanh``; a number: one layer); ``()`` for a linear map.
        low: per feature, the value mapped to -1 (default: no scaling).
        high: per feature, the value mapped to +1.
        wrap: per feature, an angle from ``low`` to ``high`` (one turn), fed as its sine and
            cosine (needs ``low``/``high``).
        coder: instead, dense tile indicators of the features (``phi / T``).
        n_states: instead, a one-hot of the node's abstract state (``n_inputs`` unused).
        bias: the layers have biases.
        init_seed: seed of the hidden layers' initial weights (the output layer starts at 0:
            every learner starts from the same weights, the policy from its centre).
        adam_lr: Adam's step size (Kingma & Ba 2015; betas 0.9, 0.999): the head moves by Adam
            over Equation 5.2's estimate ``F`` instead of by ``alpha F`` (Algorithm 3 line 16;
            ``None``, the default). The estimate is the same; Adam scales each weight's step.
    """

    BETAS, EPS = (0.9, 0.999), 1e-8

    def __init__(
        self,
        name: str,
        n_inputs: int,
        n_outputs: int,
        hidden: int | Sequence[int] = (32,),
        low: Sequence[float] | None = None,
        high: Sequence[float] | None = None,
        wrap: Sequence[bool] | None = None,
        coder: TileCoder | None = None,
        n_states: int | None = None,
        bias: bool = True,
        init_seed: int = 0,
        adam_lr: float | None = None,
    ) -> None:
        if adam_lr is not None and not adam_lr > 0:
            raise ValueError(f"adam_lr must be positive, got {adam_lr}")
        if (low is None) != (high is None):
            raise ValueError("give low and high together, or a coder, or neither")
        if sum(x is not None for x in (low, coder, n_states)) > 1:
            raise ValueError("give one input encoding: low and high, a coder, or n_states")
        if wrap is not None and low is None:
            raise ValueError("wrap needs low and high (the angle's turn)")
        n_in = None if n_states is None else int(n_states)
        width_in = _input_width(int(n_inputs), wrap, coder, n_in)
        hidden = (hidden,) if isinstance(hidden, int) else tuple(hidden)
        widths = [width_in, *(int(h) for h in hidden), int(n_outputs)]
        shapes = [(a, b) for a, b in zip(widths[:-1], widths[1:], strict=True)]
        n_params = sum(a * b + (b if bias else 0) for a, b in shapes)
        super().__init__(name, 1, n_params)
        self.n_inputs, self.bias, self.n_states_in = int(n_inputs), bool(bias), n_in
        self.coder, self.shapes, self.width = coder, shapes, n_params
        self.adam_lr = None if adam_lr is None else float(adam_lr)
        self.steps_itself = adam_lr is not None
        self._scaling(low, high, wrap)
        theta0 = _initial_weights(shapes, self.bias, int(init_seed))
        self.register_buffer("theta0", theta0, persistent=False)

    def _scaling(self, low, high, wrap) -> None:
        for name in ("x_mid", "x_half", "wrapped", "plain"):
            self.register_buffer(name, None, persistent=False)
        if low is None:
            return
        lo, hi = torch.tensor(low, dtype=torch.float32), torch.tensor(high, dtype=torch.float32)
        if lo.shape != (self.n_inputs,) or hi.shape != lo.shape or not bool((hi > lo).all()):
            raise ValueError(f"low and high need {self.n_inputs} values each with low < high")
        self.register_buffer("x_mid", (hi + lo) / 2, persistent=False)
        self.register_buffer("x_half", (hi - lo) / 2, persistent=False)
        if wrap is not None and any(wrap):  # (the angles' columns and the others')
            flags = [bool(w) for w in wrap]
            at = [[k for k, w in enumerate(flags) if w == side] for side in (True, False)]
            self.register_buffer("wrapped", torch.tensor(at[0]), persistent=False)
            self.register_buffer("plain", torch.tensor(at[1], dtype=torch.long), persistent=False)

    def bind(self, bank: TableBank, table: int) -> None:
        """Store the parameters in ``bank``'s block ``table``, starting at the initial weights."""
        super().bind(bank, table)
        with torch.no_grad():
            bank.block(table).copy_(self.theta0.to(bank.store.device).view(1, 1, -1))
        if self.steps_itself:  # Adam's moments per learner and weight, and its step count
            zeros = torch.zeros(bank.block(table).shape[0], self.width, device=bank.store.device)
            self.register_buffer("adam_m", zeros)
            self.register_buffer("adam_v", zeros.clone())
            self.register_buffer("adam_t", torch.zeros(1, device=bank.store.device))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        if self.steps_itself:  # (a checkpoint made without Adam: its moments start at 0)
            for name in ("adam_m", "adam_v", "adam_t"):
                state_dict.setdefault(prefix + name, torch.zeros_like(getattr(self, name)))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def optimizer_step(self, estimate: torch.Tensor) -> torch.Tensor:
        """Adam's step ``[P, K]`` for the estimate ``F [P, K]`` (ascent: ``+lr m^ / sqrt(v^)``)."""
        (b1, b2), g = self.BETAS, estimate.to(self.adam_m.dtype)
        self.adam_t += 1
        self.adam_m.mul_(b1).add_(g, alpha=1 - b1)
        self.adam_v.mul_(b2).addcmul_(g, g, value=1 - b2)
        m_hat = self.adam_m / (1 - b1**self.adam_t)
        v_hat = self.adam_v / (1 - b2**self.adam_t)
        return self.adam_lr * m_hat / (v_hat.sqrt() + self.EPS)

    def _check_features(self, graph: TaskGraph, node: int) -> None:
        x = graph.nodes[node]
        if self.n_states_in is not None:
            if x.n_states != self.n_states_in:
                raise GraphError(
                    f"PG node {x.name!r} has {x.n_states} abstract states, the head "
                    f"{self.name!r} a one-hot of {self.n_states_in}"
                )
            return
        dims = self.coder.resolution.numel() if self.coder is not None else self.n_inputs
        if x.n_features < dims:
            raise GraphError(f"PG node {x.name!r} needs >= {dims} features, has {x.n_features}")

    def inputs(self, features: torch.Tensor | None, state: torch.Tensor | None = None):
        """The MLP's inputs ``[n, W]`` from the node's features (or abstract states ``[n]``)."""
        if self.n_states_in is not None:
            return torch.nn.functional.one_hot(state, self.n_states_in).float()
        if self.coder is not None:
            tiles = self.coder(features[:, : self.coder.resolution.numel()])
            phi = torch.zeros(tiles.shape[0], self.coder.n_features, device=features.device)
            return phi.scatter_add_(
                1, tiles, torch.full_like(phi[:, : tiles.shape[1]], 1 / tiles.shape[1])
            )
        x = features[:, : self.n_inputs]
        if self.x_mid is None:
            return x
        x = (x - self.x_mid) / self.x_half
        if self.wrapped is None:
            return x
        angle = math.pi * x.index_select(1, self.wrapped)  # (one turn: low .. high, -pi .. pi)
        plain = x.index_select(1, self.plain)
        return torch.cat([plain, torch.sin(angle), torch.cos(angle)], 1)

    def forward_rows(self, params: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The MLP's outputs ``[n, n_outputs]`` for per-row parameters ``params [n, K]``."""
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
        return h[:, 0, :]

    def row_params(self, theta: torch.Tensor, base: torch.Tensor):
        """``(index [n, K], params [n, K])``: each row's weights, a leaf that requires grad."""
        index = base[:, None] + torch.arange(self.width, device=base.device)
        params = theta.index_select(0, index.reshape(-1)).view(index.shape)
        return index, params.detach().requires_grad_(True)


class MLPGaussianPolicyHead(ActionRange, MLPPolicyHead):
    """Gaussian over ``A_theta(x)``, an MLP of the node's features, squashed into the range.

    Args:
        name: the head's name (its subtask or group).
        n_inputs: features the MLP reads (the first ``n_inputs`` of the node's).
        hidden: hidden widths (``tanh``; a number: one layer); ``()`` for a linear mean.
        sigma: standard deviation of every entry of ``u``.
        action_low: lower end of the action range (a number, or one per entry); ``None``
            (default): the env's ``action_bounds``, set by the trainer at its start
            (``hrl_torch.learners.action_range``; before 0.2.1 the default was +-15).
        action_high: upper end (``None`` with ``action_low``).
        low, high, coder, bias, init_seed: the inputs and weights (``MLPPolicyHead``).
        action_dim: entries of the action vector (the continuous child's ``action_dim``).
        wrap, adam_lr: as ``MLPPolicyHead``'s.
    """

    continuous = True
    range_hint = "MLPGaussianPolicyHead(action_low=..., action_high=...)"

    def __init__(
        self,
        name: str,
        n_inputs: int,
        hidden: int | Sequence[int] = (32,),
        sigma: float = 1.0,
        action_low: float | Sequence[float] | None = None,
        action_high: float | Sequence[float] | None = None,
        low: Sequence[float] | None = None,
        high: Sequence[float] | None = None,
        coder: TileCoder | None = None,
        bias: bool = True,
        init_seed: int = 0,
        action_dim: int = 1,
        wrap: Sequence[bool] | None = None,
        adam_lr: float | None = None,
    ) -> None:
        if sigma <= 0:
            raise ValueError(f"sigma must be positive, got {sigma}")
        if int(action_dim) < 1:
            raise ValueError(f"action_dim must be >= 1, got {action_dim}")
        super().__init__(
            name,
            n_inputs,
            int(action_dim),
            hidden,
            low,
            high,
            wrap,
            coder,
            None,
            bias,
            init_seed,
            adam_lr,
        )
        self.sigma, self.action_dim = float(sigma), int(action_dim)
        self.n_uniforms = 1 + 2 * math.ceil(self.action_dim / 2)
        self.init_range(action_low, action_high, old_default=_OLD_RANGE)

    def check(self, graph: TaskGraph, node: int) -> None:
        """The node needs one continuous primitive child of ``action_dim`` and the features."""
        x = graph.nodes[node]
        children = [graph.node(c) for c in x.children_names]
        if len(children) != 1 or not children[0].is_primitive or not children[0].action_dim:
            raise GraphError(f"PG node {x.name!r}: a Gaussian head needs one continuous child")
        if children[0].action_dim != self.action_dim:
            raise GraphError(
                f"PG node {x.name!r}: its child acts with {children[0].action_dim} numbers, "
                f"the head {self.name!r} gives {self.action_dim}"
            )
        self._check_features(graph, node)

    def mean(self, params: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """``A_theta(x)``: ``[n]`` (one action entry) or ``[n, action_dim]``."""
        out = self.forward_rows(params, x)
        return out[:, 0] if self.action_dim == 1 else out

    def act(self, theta: torch.Tensor, inp: PolicyInput, greedy: bool) -> PolicyChoice:
        """``u = A + sigma z`` (or ``A``), action ``squash(u)``; the score by autograd."""
        x = self.inputs(inp.features)
        with torch.enable_grad():
            index, params = self.row_params(theta, inp.base)
            mean = self.mean(params, x)
            if self.action_dim == 1:
                noise = 0.0 if greedy else self.sigma * box_muller(inp.u[:, 1], inp.u[:, 2])
            else:
                noise = 0.0 if greedy else self.sigma * normals(inp.u, self.action_dim)
            pre = mean.detach() + noise
            scale = torch.full_like(mean, self.sigma)  # (no check: nothing read back)
            log_mu = Normal(mean, scale, validate_args=False).log_prob(pre)
            (score,) = torch.autograd.grad(log_mu.sum(), params)
        flag = torch.full_like(inp.base, greedy, dtype=torch.bool)
        child = torch.zeros_like(inp.base)
        return PolicyChoice(child, flag, self.squash(pre), index, score)


class MLPCategoricalPolicyHead(MLPPolicyHead):
    """A softmax over the node's available children of logits ``L_theta(x)``, an MLP.

    Args:
        name: the head's name (its subtask or group).
        n_inputs: features the MLP reads (0 with ``n_states``).
        n_children: the node's children (the logits' width).
        hidden: hidden widths (``tanh``); ``()``: linear logits (with ``n_states``, the
            tabular softmax of ``SoftmaxPolicyHead`` plus a bias).
        low, high, wrap, coder, n_states, bias, init_seed, adam_lr: the inputs, weights and
            step (``MLPPolicyHead``).
    """

    def __init__(
        self,
        name: str,
        n_inputs: int,
        n_children: int,
        hidden: int | Sequence[int] = (32,),
        low: Sequence[float] | None = None,
        high: Sequence[float] | None = None,
        wrap: Sequence[bool] | None = None,
        coder: TileCoder | None = None,
        n_states: int | None = None,
        bias: bool = True,
        init_seed: int = 0,
        adam_lr: float | None = None,
    ) -> None:
        if int(n_children) < 1:
            raise ValueError(f"n_children must be >= 1, got {n_children}")
        super().__init__(
            name,
            n_inputs,
            n_children,
            hidden,
            low,
            high,
            wrap,
            coder,
            n_states,
            bias,
            init_seed,
            adam_lr,
        )
        self.n_children = int(n_children)

    def check(self, graph: TaskGraph, node: int) -> None:
        """The node's children are discrete, as many as the logits, and it has the inputs."""
        x = graph.nodes[node]
        children = [graph.node(c) for c in x.children_names]
        if any(c.is_primitive and c.action_dim for c in children):
            raise GraphError(f"PG node {x.name!r}: a categorical head needs discrete children")
        if len(children) != self.n_children:
            raise GraphError(
                f"PG node {x.name!r} has {len(children)} children, the head {self.name!r} "
                f"{self.n_children} logits"
            )
        self._check_features(graph, node)

    def logits(self, params: torch.Tensor, x: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
        """``L_theta(x)`` ``[n, n_children]`` with the unavailable children at ``-inf``.

        A row with no available child (a row of another node) gets zeros.
        """
        raw = self.forward_rows(params, x)
        masked = raw.masked_fill(~ok, -math.inf)
        return torch.where(ok.any(-1, keepdim=True), masked, raw * 0.0)

    def act(self, theta: torch.Tensor, inp: PolicyInput, greedy: bool) -> PolicyChoice:
        """Sample from (or take the mode of) the softmax; the score by autograd."""
        ok = inp.available[:, : self.n_children]
        x = self.inputs(inp.features, inp.state)
        with torch.enable_grad():
            index, params = self.row_params(theta, inp.base)
            logits = self.logits(params, x, ok)
            dist = Categorical(logits=logits, validate_args=False)
            best = masked_argmax(logits.detach(), ok)
            pick = best if greedy else sample_categorical(dist.probs.detach(), inp.u[:, 0])
            (score,) = torch.autograd.grad(dist.log_prob(pick).sum(), params)
        return PolicyChoice(pick, pick == best, None, index, score)
