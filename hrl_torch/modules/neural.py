"""Neural heads: a population of small MLPs, one per (learner, table node), in one batched call.

``StackedMLP`` holds ``P x T`` independent networks ``f_{p,t}`` (learner ``p``, table node
``t``) as stacked parameters ``[P, T, ...]``; one ``forward`` evaluates any rows of any
learners and nodes (``torch.bmm`` over the learners), so a population of ten seeds is one
call, not ten. The inputs are sparse binary features: each (node, abstract state) turns on
``K`` of the node's ``F`` input units (``one_hot_features``: the abstract index itself;
``factored_features``: one unit per digit of a mixed-radix state, e.g. taxi's ``Get`` state
``taxi_loc * 5 + passenger`` as row, column and passenger), so the first layer is a gather of
``K`` weight rows (the same numbers as the one-hot product, without the product).

``StackedAdam`` is Adam (Kingma and Ba 2015, Algorithm 1) over those stacked parameters, with
its moments and step count as buffers: elementwise, so learner ``p``'s parameters move exactly
as in a run of ``p`` alone, and with no value read back to the host (the step count is a
tensor; ``torch.optim.Adam`` reads it on the CPU unless ``capturable``, which the CPU refuses).

``NeuralCompletionHead`` names one node's block of the network in ``learner.heads``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import torch
from torch import nn

from hrl_torch.modules.heads import Head


def one_hot_features(n_states: Sequence[int]) -> torch.Tensor:
    """``[T, S, 1]`` active input units: state ``s`` of every node turns on unit ``s``."""
    width = max([1, *n_states])
    units = torch.arange(width)[:, None]
    return units.expand(len(n_states), width, 1).clone()


def factored_features(
    n_states: Sequence[int], radices: Sequence[Sequence[int] | None]
) -> torch.Tensor:
    """``[T, S, K]`` active units: one per mixed-radix digit of the state (most significant first).

    ``radices[t]`` (``None``: one-hot) factors node ``t``'s ``n_states[t]`` states, e.g. ``(5,
    5, 5)`` for ``(row * 5 + col) * 5 + passenger``; digit ``k`` turns on unit ``sum(radices[:k])
    + digit``. Nodes with fewer digits than ``K`` repeat their last unit (a unit counted twice
    is a fixed scale, harmless); an error names a node whose radices do not multiply out.
    """
    digits = []
    for t, n in enumerate(n_states):
        r = [n] if radices[t] is None else [int(x) for x in radices[t]]
        if math.prod(r) != n:
            raise ValueError(f"node {t}: radices {tuple(r)} multiply to {math.prod(r)}, not {n}")
        digits.append(r)
    width, k_max = max([1, *n_states]), max(len(r) for r in digits)
    out = torch.zeros(len(n_states), width, k_max, dtype=torch.long)
    for t, r in enumerate(digits):
        s = torch.arange(width).clamp_max(max(n_states[t] - 1, 0))
        offset, cols = 0, []
        for k, radix in enumerate(r):
            below = math.prod(r[k + 1 :])
            cols.append(offset + (s // below) % radix)
            offset += radix
        cols += [cols[-1]] * (k_max - len(cols))
        out[t] = torch.stack(cols, -1)
    return out


class StackedMLP(nn.Module):
    """``P x T`` MLPs ``f_{p,t}``: sparse binary inputs -> ``hidden`` ReLU layers -> ``O`` outputs.

    Parameters: ``w0 [P, T, F, H]``, ``b0 [P, T, H]``, then per further layer ``w<k> [P, T,
    H, H']``, ``b<k> [P, T, H']``; the output layer's bias starts at ``init`` (e.g. pessimistic
    completion values) and its weights small (``out_scale``), so the outputs start near it.
    The weights are drawn once from ``init_seed`` (a CPU generator, then copied to every
    learner: each learner starts from the same weights whatever the population's size and
    order; the seeds differ in their envs and choices).

    Args:
        n_learners: population size ``P``.
        n_tables: nodes ``T``.
        n_inputs: input units per node ``F``.
        n_outputs: outputs per node ``O``.
        hidden: widths of the hidden layers (a number: one layer).
        init: the outputs' initial value.
        init_seed: seed of the initial weights.
        out_scale: standard deviation scale of the output layer's initial weights.
    """

    def __init__(
        self,
        n_learners: int,
        n_tables: int,
        n_inputs: int,
        n_outputs: int,
        hidden: int | Sequence[int] = (64,),
        init: float = 0.0,
        init_seed: int = 0,
        out_scale: float = 1.0,
    ) -> None:
        super().__init__()
        hidden = (hidden,) if isinstance(hidden, int) else tuple(hidden)
        if not hidden or any(int(h) < 1 for h in hidden):
            raise ValueError(f"hidden must be one or more positive widths, got {hidden!r}")
        gen = torch.Generator().manual_seed(int(init_seed))
        widths = [int(n_inputs), *(int(h) for h in hidden), int(n_outputs)]
        self.n_layers = len(widths) - 1
        self.n_learners, self.n_tables = n_learners, n_tables
        for k, (fan_in, fan_out) in enumerate(zip(widths[:-1], widths[1:], strict=True)):
            last = k == self.n_layers - 1
            # (He-uniform; a sparse first layer sees ~1 unit: its fan-in is 1; the output
            # layer LeCun-uniform scaled by ``out_scale``)
            gain = 6.0 if not last else 3.0 * out_scale**2
            bound = math.sqrt(gain / (1 if k == 0 else fan_in))
            w = (torch.rand(n_tables, fan_in, fan_out, generator=gen) * 2 - 1) * bound
            b = torch.full((n_tables, fan_out), float(init) if last else 0.0)
            self.register_parameter(f"w{k}", nn.Parameter(w.expand(n_learners, -1, -1, -1).clone()))
            self.register_parameter(f"b{k}", nn.Parameter(b.expand(n_learners, -1, -1).clone()))

    def forward(self, table: torch.Tensor, units: torch.Tensor) -> torch.Tensor:
        """``f_{p,t}(x)`` for rows of every learner: ``[P, N, O]``.

        ``table [P, N]``: each row's node; ``units [P, N, K]``: its active input units (row
        ``n`` of learner ``p`` reads learner ``p``'s networks). Layers after the first are
        computed for every node and the row's node taken (``O`` and ``H`` are small: the
        waste is a factor ``T`` of a small product, against a gather of ``N`` weight matrices).
        """
        p, n = table.shape
        t_all = self.n_tables
        w0, b0 = self.w0, self.b0
        learner = torch.arange(p, device=table.device)[:, None]
        node = learner * t_all + table  # [P, N]
        flat = (node[..., None] * w0.shape[2] + units).reshape(-1)
        h = w0.reshape(-1, w0.shape[-1]).index_select(0, flat).view(p, n, units.shape[-1], -1)
        h = h.sum(2) + b0.reshape(-1, b0.shape[-1]).index_select(0, node.reshape(-1)).view(p, n, -1)
        pick = table[..., None, None]
        for k in range(1, self.n_layers):
            h = torch.relu(h)
            w, b = getattr(self, f"w{k}"), getattr(self, f"b{k}")
            out = w.shape[-1]
            every = torch.bmm(h, w.permute(0, 2, 1, 3).reshape(p, w.shape[2], t_all * out))
            h = every.view(p, n, t_all, out).gather(2, pick.expand(p, n, 1, out)).squeeze(2)
            h = h + b.reshape(-1, out).index_select(0, node.reshape(-1)).view(p, n, out)
        return h

    def node_parameters(self, table: int) -> dict[str, torch.Tensor]:
        """Node ``table``'s parameters, ``[P, ...]`` views."""
        return {name: value[:, table] for name, value in self.named_parameters()}


class StackedAdam(nn.Module):
    """Adam over stacked parameters, state in buffers (Kingma and Ba 2015, Algorithm 1).

    ``m <- b1 m + (1-b1) g``, ``v <- b2 v + (1-b2) g^2``, ``theta <- theta - lr m^ / (sqrt(v^)
    + eps)`` with ``m^ = m / (1 - b1^t)``, ``v^ = v / (1 - b2^t)``; elementwise, so the
    population's learners never mix.

    Args:
        params: the parameters by name (their shapes; ``step`` is given them).
        lr: step size.
        betas: the moments' decay rates.
        eps: the denominator's floor.
    """

    def __init__(
        self,
        params: Mapping[str, nn.Parameter],
        lr: float = 1e-3,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        super().__init__()
        if not lr > 0:
            raise ValueError(f"lr must be positive, got {lr}")
        self.names = list(params)
        self.lr, self.betas, self.eps = float(lr), tuple(float(b) for b in betas), float(eps)
        self.register_buffer("t", torch.zeros(()))
        for name, p in params.items():
            self.register_buffer(f"m_{name}", torch.zeros_like(p.detach()))
            self.register_buffer(f"v_{name}", torch.zeros_like(p.detach()))

    @torch.no_grad()
    def step(self, params: Mapping[str, torch.Tensor], grads: Sequence[torch.Tensor]) -> None:
        """One Adam step of ``params`` (by name) with ``grads`` (in ``names`` order), in place."""
        b1, b2 = self.betas
        self.t.add_(1.0)
        c1 = 1.0 - torch.pow(b1, self.t)
        c2 = 1.0 - torch.pow(b2, self.t)
        for name, g in zip(self.names, grads, strict=True):
            m, v = self.get_buffer(f"m_{name}"), self.get_buffer(f"v_{name}")
            m.mul_(b1).add_(g, alpha=1.0 - b1)
            v.mul_(b2).addcmul_(g, g, value=1.0 - b2)
            denom = (v / c2).sqrt_().add_(self.eps)
            params[name].addcdiv_(m / c1, denom, value=-self.lr)


class NeuralCompletionHead(Head):
    """One node's block of a ``StackedMLP`` (``learner.heads[name]``), for reading.

    Its tensors are saved once, by the learner's network (``completion.w0`` ...), not here.
    """

    def __init__(self, name: str, net: StackedMLP, table: int) -> None:
        super().__init__(name)
        self.table = table
        object.__setattr__(self, "_net", net)  # (the learner's)

    def __getitem__(self, key: str) -> torch.Tensor:
        """One parameter of this node, e.g. ``head["w0"]`` ``[P, F, H]``."""
        return self._net.node_parameters(self.table)[key]

    def extra_repr(self) -> str:
        """The node's parameter shapes."""
        shapes = self._net.node_parameters(self.table).items()
        return ", ".join(f"{k}={tuple(v.shape)}" for k, v in shapes)
