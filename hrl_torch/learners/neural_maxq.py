"""MAXQ-Q with neural completions: ``C(i, s, a)`` an MLP per subtask, trained by autograd.

The values and targets are MAXQ-Q's (``hrl_torch.learners.maxq``, Dietterich 2000, Table 4)::

    Q(i, s, a) = V(a, s) + C(i, s, a),   V(i, s) = Q(i, s, a*)      (Equations 3.5, 3.6)
    C(i, s, a)  <- gamma^N [C(i, s', a*) + V(a*, s')]              (Table 4, the C line)
    C~(i, s, a) <- R~ + gamma^N [R~_i(s') or C~(i, s', a*) + V(a*, s')]
    V(a, s)     <- (1-alpha) V + alpha r                            (primitive a: a table)

Where the table moves ``C`` a step ``alpha`` toward its target, here the completions of every
non-primitive node are the outputs of a small MLP over the node's abstract state (one-hot or
factored units, ``hrl_torch.modules.neural``), and each learner takes ``updates`` Adam steps
per env step on its mean squared TD error over the transitions that finished::

    L_p(theta_p) = mean over finished (i, s, a) of learner p of 1/2 (C_theta(i, s, a) - target)^2

(the semi-gradient: the target, computed from the values ``evaluate`` made at ``s'``, is a
constant). Without a separate target network: at taxi's size the values ``evaluate`` made at
``s'`` this step serve (measured in docs/neural-heads.md).

The network is one ``StackedMLP`` over every (learner, node): ``evaluate`` is one forward over
all rows and nodes, ``update`` one forward (and backward) per Adam step, whatever the
population size. Rows are learner-major with equal counts (row ``b`` of ``B = P * E`` belongs
to learner ``b // E``: the executor's, the evaluations' and ``FrozenValues``' layout).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch

from hrl_torch.common.ops import (
    columns,
    entries,
    lookup,
)
from hrl_torch.execution.transitions import LEVEL, PRIMITIVE
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners.base import TabularLearner, finished
from hrl_torch.learners.maxq import MaxQLearner, bottom_up_values
from hrl_torch.modules.heads import attach_table_heads
from hrl_torch.modules.neural import (
    NeuralCompletionHead,
    StackedAdam,
    StackedMLP,
    factored_features,
    one_hot_features,
)
from hrl_torch.modules.schedules import Schedule


def learner_rows(learner: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """``learner [B]`` repeated over ``like``'s trailing dimensions, flattened."""
    shape = (learner.shape[0],) + (1,) * (like.dim() - 1)
    return learner.view(shape).expand_as(like).reshape(-1)


class NeuralMaxQLearner(TabularLearner):
    """MAXQ-Q whose completions are MLPs (one per learner and subtask), the leaves' ``V`` tables.

    Args:
        graph: the task graph.
        n_learners: population size ``P``.
        alpha: step size of the primitives' ``V`` tables (number or schedule).
        gamma: discount factor.
        lr: Adam's step size for the completion networks.
        hidden: hidden widths of every node's MLP (a number: one hidden layer).
        encoding: ``"onehot"`` (a unit per abstract state) or ``"factored"`` (a unit per
            digit of the state in ``radices``).
        radices: for ``"factored"``, each subtask's mixed radices by name (e.g. ``{"Get":
            (5, 5, 5)}``); subtasks not named are one-hot.
        init: the completions' initial value (the output layer starts at it exactly).
        init_seed: seed of the hidden layers' initial weights (the same for every learner).
        updates: Adam steps per env step on each step's transitions.
        tables: subtasks whose completions stay tables (MAXQ-Q's update with ``alpha``), e.g.
            ``("Root",)``: a tabular root over neural subtasks in one graph.
        init_nodes: initial completions of the named subtasks instead of ``init`` (their
            networks' output biases, or their tables).
    """

    uses = frozenset()
    value_keys = ("V", "V_int", "Q")
    targets = MaxQLearner.targets  # (Dietterich's Table 4 targets, shared with the tables)

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        alpha: float | Schedule = 0.5,
        gamma: float = 1.0,
        lr: float = 0.01,
        hidden: int | Sequence[int] = 64,
        encoding: str = "onehot",
        radices: Mapping[str, Sequence[int]] | None = None,
        init: float = 0.0,
        init_seed: int = 0,
        updates: int = 1,
        tables: Sequence[str] = (),
        init_nodes: Mapping[str, float] | None = None,
    ) -> None:
        super().__init__(graph, n_learners, alpha, gamma, per_instance=False)
        if encoding not in ("onehot", "factored"):
            raise ValueError(f"encoding must be 'onehot' or 'factored', got {encoding!r}")
        if int(updates) < 1:
            raise ValueError(f"updates must be >= 1, got {updates}")
        self.updates = int(updates)
        self.internal = bool(graph.internal_nodes)
        names = [graph.names[t] for t in self.plan.order.tolist()]
        radices, init_nodes = dict(radices or {}), dict(init_nodes or {})
        for what, given in (("radices", radices), ("tables", tables), ("init_nodes", init_nodes)):
            unknown = sorted(set(given) - set(names))
            if unknown:
                raise GraphError(f"{what}: {unknown} are not subtasks of the graph")
        n_inputs = self._encode_states(names, encoding, radices)
        self.width = self.layout.max_children
        n_out = self.width * (2 if self.internal else 1)
        self.completion = StackedMLP(
            n_learners, len(names), n_inputs, n_out, hidden, init, init_seed
        )
        self.optimizer = StackedAdam(dict(self.completion.named_parameters()), lr)
        self._make_heads(graph, names, tables, init, init_nodes)
        self._per_state: dict = {}

    def _encode_states(self, names: list[str], encoding: str, radices: dict) -> int:
        """Every planned node's abstract states as unit rows (``units``); the input width."""
        lay, plan = self.layout, self.plan
        n_states = [int(lay.table_n_states[t]) for t in plan.order.tolist()]
        if encoding == "onehot":
            units = one_hot_features(n_states)
        else:
            units = factored_features(n_states, [radices.get(n) for n in names])
        self.n_state_rows = units.shape[1]  # S: rows of every node's unit table
        self.register_buffer("units", units.reshape(-1, units.shape[-1]), persistent=False)
        pos = torch.zeros(lay.n_tables, dtype=torch.long)
        pos[plan.order] = torch.arange(len(names))
        self.register_buffer("table_pos", pos, persistent=False)
        return int(units.max()) + 1

    def _make_heads(
        self, graph: TaskGraph, names: list[str], tables, init: float, init_nodes: dict
    ) -> None:
        """A neural head per planned node, a table head for those in ``tables``; their starts."""
        lay = self.layout
        self.V = self.primitive_bank()
        tabular = torch.tensor([n in tables for n in names], dtype=torch.bool)
        self.register_buffer("tabular", tabular, persistent=False)  # [Tc], plan order
        on_tables = tabular[self.table_pos] & ~lay.table_is_primitive
        self.register_buffer("table_tabular", on_tables, persistent=False)
        banks = {"V": self.V}
        self.C = self.C_int = None
        if tables:  # (a block per subtask, read and written only for those in ``tables``)
            self.C = banks["C"] = self.completion_bank(init)
            if self.internal:
                self.C_int = banks["C_int"] = self.completion_bank(init)
        self.heads = attach_table_heads(self, graph, lay, banks)
        last = getattr(self.completion, f"b{self.completion.n_layers - 1}")
        with torch.no_grad():
            for k, name in enumerate(names):
                if name in init_nodes:
                    last[:, k].fill_(float(init_nodes[name]))
                if name not in tables:
                    self.heads[name] = NeuralCompletionHead(name, self.completion, k)
                elif name in init_nodes:
                    for key in ("C", "C_int") if self.internal else ("C",):
                        self.heads[name][key].fill_(float(init_nodes[name]))

    # ------------------------------------------------------------------ values
    def _context(self, ctx: StepContext):
        """``(penalty [B, Tc, A], dead [B, Tc], unit row [B, Tc])`` of the planned nodes."""
        plan, g = self.plan, self.graph
        if ctx.table_row is not None:
            key = (id(g.tab_abstract), g.tab_abstract.device)
            cached = self._per_state.get(key)
            if cached is None:
                blocked = ~g.tab_available[:, plan.node]
                dead = g.tab_blocked[:, plan.node] | blocked.all(-1)
                penalty = torch.zeros(blocked.shape, device=blocked.device)
                penalty.masked_fill_(blocked, -torch.inf)
                state = g.tab_abstract[:, plan.node].clamp(0, self.n_state_rows - 1)
                row = self.unit_rows(torch.arange(len(plan.node), device=state.device), state)
                cached = self._per_state[key] = (penalty, dead, row)
            return tuple(t.index_select(0, ctx.table_row) for t in cached)
        blocked = ~columns(ctx.available, plan.node)
        dead = columns(ctx.blocked, plan.node) | blocked.all(-1)
        penalty = torch.zeros(blocked.shape, device=blocked.device).masked_fill_(
            blocked, -torch.inf
        )
        state = columns(ctx.abstract, plan.node).clamp(0, self.n_state_rows - 1)
        return penalty, dead, self.unit_rows(self._arange_tc(), state)

    def _arange_tc(self) -> torch.Tensor:
        return torch.arange(self.plan.node.shape[0], device=self.plan.node.device)

    def unit_rows(self, pos: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """Row of ``self.units`` of node position ``pos`` at ``state`` (broadcast)."""
        return pos * self.n_state_rows + state

    def completions(
        self, pos: torch.Tensor, unit_row: torch.Tensor, learner: torch.Tensor
    ) -> torch.Tensor:
        """The networks' outputs ``[B, ..., O]`` at node positions ``pos`` and unit rows.

        ``pos``, ``unit_row`` ``[B, ...]`` of the rows ``learner [B]``. Rows with the same
        number for every learner (``RowLayout.blocks``; sorted into learner-major blocks where
        they interleave, ``RowLayout.order``) take one forward of ``P`` batched networks; any
        other rows (e.g. ``greedy_table``'s, all of one learner) one forward of every
        learner's network on all rows, each row keeping its own learner's outputs.
        """
        p = self.n_learners
        layout = self.row_layout(learner)  # (told by the agent: no read)
        if layout is not None and layout.blocks == p:
            order = layout.order  # (rows interleaved: sorted into blocks and back)
            if order is not None:
                pos, unit_row = pos.index_select(0, order[0]), unit_row.index_select(0, order[0])
            units = self.units.index_select(0, unit_row.reshape(-1))
            out = self.completion(pos.reshape(p, -1), units.view(p, -1, units.shape[-1]))
            out = out.view(*pos.shape, out.shape[-1])
            return out if order is None else out.index_select(0, order[1])
        units = self.units.index_select(0, unit_row.reshape(-1))
        n, k = units.shape
        every = self.completion(pos.reshape(1, -1).expand(p, n), units.expand(p, n, k))
        picked = every.gather(
            0, learner_rows(learner, pos)[None, :, None].expand(1, n, every.shape[-1])
        )
        return picked.view(*pos.shape, every.shape[-1])

    def evaluate(self, ctx: StepContext) -> None:
        """Bottom-up ``V(i, s)``, ``max_a Q~(i, s, a)`` and the rows ``Q~(i, s, .)``.

        As ``MaxQLearner.evaluate``, with the completion rows from the networks (no graph
        kept: the values are constants of the targets). ``ctx.values``: ``V``, ``V_int``
        ``[B, T]``; ``Q`` ``[B, Tc, A]`` (plan order).
        """
        penalty, dead, unit_row = self._context(ctx)
        pos = self._arange_tc().expand_as(unit_row)
        with torch.no_grad():
            out = self.completions(pos, unit_row, ctx.learner)
        a = self.width
        rows = (out[..., :a], out[..., a:]) if self.internal else (out,)
        if self.C is not None:  # the tabular subtasks' rows from their tables
            banks = (self.C, self.C_int) if self.internal else (self.C,)
            _, _, table_rows = self.composite_rows(ctx, *banks)
            keep = self.tabular[:, None]
            rows = tuple(torch.where(keep, t, r) for t, r in zip(table_rows, rows, strict=True))
        bottom_up_values(self, ctx, penalty, dead, rows)

    # ------------------------------------------------------------------ updates
    def update(self, batch, step: int) -> None:
        """The primitives' table update and ``updates`` Adam steps on the completion networks."""
        fields = entries(batch)
        level, values = entries(fields[LEVEL]), entries(fields["values"])
        learner = fields["learner"]
        table = self.level_table(level)
        terminal, ran = level["terminal"], level["ran"]
        valid = finished(level)
        v_next = values["V"].gather(1, table)
        v_next_int = values["V_int"].gather(1, table) if self.internal else v_next
        target, target_int = self.targets(level, terminal, v_next, v_next_int)
        state = level["state"].clamp_min(0)
        # V(a, s) <- (1-alpha) V + alpha r on the primitive's level (Table 4)
        reward = entries(fields[PRIMITIVE])["reward"][:, None].expand_as(target)
        v_index = self.V.index(learner[:, None], table, state, 0)
        distinct = self.rows_distinct(learner)
        self.V.update(v_index, reward, self.alpha(step), ran, distinct)
        teach = valid & ~ran
        if self.C is not None:  # the tabular subtasks: C <- (1-alpha) C + alpha target
            on_table = teach & lookup(self.table_tabular, table)
            where = (learner[:, None], table, state, level["child"].clamp_min(0))
            self.C.update(self.C.index(*where), target, self.alpha(step), on_table, distinct)
            if self.internal:
                at = self.C_int.index(*where)
                self.C_int.update(at, target_int, self.alpha(step), on_table, distinct)
            teach = teach & ~on_table
        # C (and C~): Adam on the mean squared error toward the Table 4 targets
        pos = lookup(self.table_pos, table)
        unit_row = self.unit_rows(pos, state.clamp_max(self.n_state_rows - 1))
        child = level["child"].clamp_min(0)[..., None]
        weight = teach.float().view(self.n_learners, -1)
        weight = (weight / weight.sum(1, keepdim=True).clamp_min(1.0)).view_as(teach)
        goal = torch.stack([target, target_int], -1) if self.internal else target[..., None]
        params = dict(self.completion.named_parameters())
        for _ in range(self.updates):
            with torch.enable_grad():
                out = self.completions(pos, unit_row, learner)
                cols = [child, child + self.width] if self.internal else [child]
                pred = torch.cat([out.gather(-1, c) for c in cols], -1)
                error = pred - goal
                loss = 0.5 * (error.square().sum(-1) * weight).sum()
                grads = torch.autograd.grad(loss, list(params.values()))
            self.optimizer.step(params, grads)
        base = self.plan.learner_base(learner, 1, 2)
        self.record_td(base, level["node"], error[..., -1].detach(), teach)

    def extra_repr(self) -> str:
        """The network's shape and optimiser."""
        net = self.completion
        return f"nodes={net.n_tables}, layers={net.n_layers}, lr={self.optimizer.lr}"
