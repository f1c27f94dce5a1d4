"""Watkins's Q(lambda) with replacing traces for the value-based nodes of a hierarchy.

The high level of the ship's hierarchical hybrid (Section 5.3) learns with Q(lambda),
epsilon-greedy choices and replacing traces. For a value node ``i`` that chose child ``a`` in
abstract state ``s``, after the child ran for time ``tau`` with (discounted) external reward
``R`` and internal reward ``r~_i``, ending in ``s'`` (the SMDP form of Sutton & Barto 1998,
Figure 7.14)::

    delta = R + r~_i + gamma^tau max_a' Q(i, s', a') - Q(i, s, a)   (terminal s': pseudo reward)
    e(i, s, .) = 0;  e(i, s, a) = 1                                  replacing traces
    Q <- Q + alpha delta e                                           every traced pair
    e <- gamma^tau lambda e

and an exploratory choice cuts the traces (Watkins): ``e = 0`` before the pair of the
exploratory child joins them, which is the textbook's cut applied when that child's transition
arrives. Traces belong to one invocation of ``i`` (per env row and stack depth) and are reset
when it ends; for the root, when the episode ends. They are sparse: the last ``trace_len`` traced
pairs per invocation (older pairs have decayed by ``lambda ** trace_len``).

Several rows of one learner may trace the same pair. Their same-step increments are combined as
a trace-weighted mean, ``Q += alpha sum_r delta_r e_r / max(1, sum_r e_r)``: exactly the update
above when one row touches the entry, never an ``n * alpha`` step when ``n`` rows do.

Only the transitions of the value nodes are learned from (``nodes``): in a hybrid hierarchy the
policy-gradient nodes below belong to another learner (``hrl_torch.learners.hybrid``). As in the
other value learners, a child aborted by an ancestor teaches nothing unless its parent terminated.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from hrl_torch.common.ops import lookup
from hrl_torch.common.per_learner import at_entries
from hrl_torch.execution.transitions import LEVEL
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.learners.base import TabularLearner
from hrl_torch.learners.pg import invocation_ended
from hrl_torch.learners.validate import check_fraction
from hrl_torch.modules.eval_plan import EvalPlan
from hrl_torch.modules.schedules import Schedule
from hrl_torch.modules.tables import TableBank


class QLambdaLearner(TabularLearner):
    """Q(lambda) with replacing traces at the value nodes of a graph (see the module docstring).

    Args:
        graph: the task graph.
        n_learners: population size ``P``.
        alpha: step size (number or schedule).
        lam: trace decay ``lambda``.
        gamma: discount factor.
        nodes: names of the value nodes (default: every subtask).
        trace_len: traced pairs kept per invocation.
        init: initial action values.
    """

    value_keys = ("V", "Q")

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        alpha: float | Schedule = 0.1,
        lam: float = 0.9,
        gamma: float = 1.0,
        nodes: Sequence[str] | None = None,
        trace_len: int = 32,
        init: float = 0.0,
    ) -> None:
        super().__init__(graph, n_learners, alpha, gamma, per_instance=False)
        names = list(nodes) if nodes is not None else [graph.names[k] for k in graph.subtasks()]
        value_node = torch.zeros(graph.n_nodes, dtype=torch.bool)
        value_node[[graph.index[n] for n in names]] = True
        lay = self.layout
        n_states = torch.where(value_node[lay.table_node], lay.table_n_states, 0)
        n_cols = lay.table_n_children.clamp_min(1)
        self.Q = TableBank(n_learners, n_states, n_cols, init, pad=lay.max_children)
        self.attach_heads(Q=self.Q)
        check_fraction(self, "lam", lam)
        self.lam = float(lam)
        self.trace_len = int(trace_len)
        self.register_buffer("value_node", value_node, persistent=False)
        ids = lay.composite_ids()
        self.value_tables = ids[value_node[lay.table_node[ids]]]
        self.plan = EvalPlan(graph, lay, keep=value_node[lay.table_node])  # value nodes only
        depths = sorted({int(d) for d in graph.inst_depth[value_node[graph.inst_node]]})
        self.register_buffer("depths", torch.tensor(depths, dtype=torch.long), persistent=False)
        self._rows: dict[str, torch.Tensor] = {}
        self._num = torch.zeros(0)
        self._den = torch.zeros(0)

    def value_nodes(self) -> set[int]:
        """The nodes named in ``nodes`` (the ones this learner chooses for)."""
        return set(self.value_node.nonzero().flatten().tolist())

    # ------------------------------------------------------------------ values
    def evaluate(self, ctx: StepContext) -> None:
        """``Q(i, s, .)`` rows and ``V(i, s) = max_a Q(i, s, a)`` at every value node.

        Only the value nodes are planned (``self.plan``); the others are worth 0 here.
        """
        blocked, dead, (q,) = self.composite_rows(ctx, self.Q)
        best = q.masked_fill(blocked, -torch.inf).amax(-1)
        value = torch.zeros(q.shape[0], self.layout.n_tables, device=q.device)
        ctx.values["V"] = value.index_copy_(1, self.plan.order, best.masked_fill(dead, 0.0))
        ctx.values["Q"] = q

    # ------------------------------------------------------------------ per-row traces
    def _row_state(self, b: int, device: torch.device) -> dict[str, torch.Tensor]:
        rows = self._rows
        if not rows or rows["ptr"].shape[0] != b:
            s, k = len(self.depths), self.trace_len
            rows.clear()
            rows.update(
                index=torch.zeros(b, s, k, dtype=torch.long, device=device),
                row=torch.full((b, s, k), -1, dtype=torch.long, device=device),
                trace=torch.zeros(b, s, k, device=device),
                ptr=torch.zeros(b, s, dtype=torch.long, device=device),
            )
        return rows

    def get_extra_state(self) -> dict:
        """Traces of the training rows (checkpoints)."""
        return {k: v.clone() for k, v in self._rows.items()}

    def set_extra_state(self, state: dict) -> None:
        """Restore ``get_extra_state``."""
        self._rows = {k: v.clone() for k, v in state.items()}

    # ------------------------------------------------------------------ updates
    def update(self, batch, step: int) -> None:
        """One Q(lambda) step for every finished child of a value node in ``batch``."""
        lay, depths = self.layout, self.depths
        b = batch.batch_size[0]
        rows = self._row_state(b, self.Q.data.device)
        level = batch[LEVEL]
        pick = lambda key: level[key].index_select(1, depths)  # noqa: E731
        node, inst, terminal = pick("node"), pick("inst"), pick("terminal")
        learner = batch["learner"][:, None].expand_as(node)
        table = lay.inst_table[inst.clamp_min(0)]
        valid = pick("valid") & self.value_node[node] & (pick("child_done") | terminal)
        continuation = torch.where(
            terminal, pick("pseudo_reward"), batch["values", "V"].gather(1, table)
        )
        discount = self.gamma ** pick("duration")
        target = pick("discounted_reward") + pick("internal_reward") + discount * continuation
        child = pick("child")
        idx = self.Q.index(learner, table, pick("state"), child)
        delta = torch.where(valid, target - self.Q.read(idx, valid), 0.0)
        self.record_td(learner, node, delta, valid)

        # only the (row, depth) pairs with a transition touch their traces: compacted on the
        # CPU, masked elsewhere (static shapes, no read; the others add 0 and keep theirs)
        alpha, fields = self.alpha(step), (pick("greedy"), idx, child, delta, discount)
        if self.static(valid.device):
            self._traces(rows, valid, None, fields, alpha)
        else:
            pair = valid.view(-1).nonzero().squeeze(1)
            if pair.numel():
                self._traces(rows, valid, pair, fields, alpha)
        # a finished invocation starts with empty traces
        ended = invocation_ended(batch, depths)
        rows["trace"] = rows["trace"].masked_fill(ended[..., None], 0.0)
        rows["row"] = rows["row"].masked_fill(ended[..., None], -1)
        rows["ptr"] = rows["ptr"].masked_fill(ended, 0)

    def _traces(self, rows, valid, pair, fields, alpha) -> None:
        """Watkins Q(lambda) on the rings of the pairs ``pair`` (flat ids).

        ``pair=None``: every pair, ``valid [B, S]`` masking the others (static shapes).
        """
        k = self.trace_len
        if pair is None:
            take = lambda x: x.reshape(-1)  # noqa: E731
            ring = {key: rows[key].view(-1, k) for key in ("index", "row", "trace")}
        else:
            take = lambda x: lookup(x.reshape(-1), pair)  # noqa: E731
            ring = {key: lookup(rows[key].view(-1, k), pair) for key in ("index", "row", "trace")}
        greedy, idx, child, delta, discount = fields
        # Watkins: an exploratory choice cuts the traces of the choices before it
        trace = torch.where(take(greedy)[:, None], ring["trace"], 0.0)
        # replacing traces: e(s, .) = 0, then e(s, a) = 1 in the next ring slot
        sa, state_row = take(idx), take(idx - child)
        trace = trace.masked_fill(ring["row"] == state_row[:, None], 0.0)
        slot = take(rows["ptr"])[:, None]
        new = {
            "index": ring["index"].scatter(1, slot, sa[:, None]),
            "row": ring["row"].scatter(1, slot, state_row[:, None]),
        }
        trace = trace.scatter(1, slot, 1.0)
        # Q <- Q + alpha delta e (same-step contributions: trace-weighted mean)
        on = valid.view(-1, 1)
        den = trace if pair is not None else torch.where(on, trace, 0.0)
        self._add(new["index"], take(delta)[:, None] * trace, den, alpha)
        # e <- gamma^tau lambda e
        new["trace"] = trace * (take(discount) * self.lam)[:, None]
        ptr = (slot[:, 0] + 1) % k
        if pair is not None:
            for key, value in new.items():
                rows[key].view(-1, k).index_copy_(0, pair, value)
            rows["ptr"].view(-1).index_copy_(0, pair, ptr)
            return
        for key, value in new.items():
            rows[key] = torch.where(on, value, ring[key]).view_as(rows[key])
        rows["ptr"] = torch.where(valid, ptr.view_as(valid), rows["ptr"])

    def _add(self, index, num, den, alpha: float) -> None:
        """``Q[i] += alpha * sum(num) / max(1, sum(den))`` over the entries per index ``i``."""
        flat = self.Q.data.view(-1)
        if self._num.shape != flat.shape:
            self._num = torch.zeros_like(flat)
            self._den = torch.zeros_like(flat)
        index = index.reshape(-1)
        self._num.index_add_(0, index, num.reshape(-1))
        self._den.index_add_(0, index, den.reshape(-1))
        step = lookup(self._num, index) / lookup(self._den, index).clamp_min(1.0)
        alpha = at_entries(alpha, index, self.Q.total, flat.dtype)  # (per learner: its own)
        flat.index_put_((index,), lookup(flat, index) + alpha * step)
        self._num.index_fill_(0, index, 0.0)
        self._den.index_fill_(0, index, 0.0)
