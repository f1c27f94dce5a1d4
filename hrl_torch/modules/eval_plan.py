"""A learner's bottom-up evaluation plan: which table rows ``learner.evaluate`` reads, in order.

``EvalPlan`` holds the static indices of evaluating a ``TableLayout``'s tables group by group
(leaves' parents first); ``hrl_torch.learners.base.TabularLearner`` builds one per learner.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import nn

from hrl_torch.common.ops import columns
from hrl_torch.hierarchy.graph import TaskGraph

if TYPE_CHECKING:
    from hrl_torch.modules.tables import TableBank, TableLayout


class EvalPlan(nn.Module):
    """Static indices of a layout's bottom-up evaluation, computed once.

    The non-primitive tables in bottom-up order (``order [Tc]``, leaves' parents first), so
    that each height group is a contiguous slice ``bounds[k] = (start, end)``: a learner reads
    the rows of all of them at once (one ``index_select`` per bank, ``rows_at``) and
    evaluates group by group (``sizes`` splits them; ``group_ids[k]`` are the group's table
    ids, ``group_children[k]`` its children's table ids flattened ``[G * A]``).

    Buffers: ``order [Tc]`` table ids, ``node [Tc]`` their graph nodes, ``child_table [Tc, A]``
    the children's table ids (padding: 0), ``child_valid [Tc, A]``, ``inst_pos [I]`` the
    position in ``order`` of each instance's table (0 for primitives), ``prims [Tp]`` the
    primitive tables and ``prim_node [Tp]`` their nodes; ``chooser_pos [Ic]`` the table
    positions of the choosing instances (``graph.choosers``). With ``keep [T]`` only those
    non-primitive tables are planned (the other instances' positions read 0).

    On a tabulated graph (``TaskGraph.tabulate``) the per-state part of ``rows_at`` (each
    table's abstract state, availability and deadness) is looked up too, from tables made
    once per bank layout.
    """

    #: largest ``states x tables x children`` looked up per state (else computed per step)
    TABULATE_LIMIT = 1 << 22

    def __init__(
        self, graph: TaskGraph, layout: TableLayout, keep: torch.Tensor | None = None
    ) -> None:
        super().__init__()
        object.__setattr__(self, "graph", graph)  # not a child module: the learner's
        groups = layout.groups[1:]
        if keep is not None:  # only the tables ``keep [T]`` (e.g. a hybrid's value nodes)
            groups = [ids[keep[ids]] for ids in groups]
            groups = [ids for ids in groups if len(ids)]
        order = torch.cat(groups) if groups else torch.zeros(0, dtype=torch.long)
        self.sizes = [len(g) for g in groups]
        starts = [sum(self.sizes[:k]) for k in range(len(self.sizes))]
        self.bounds = [(s, s + n) for s, n in zip(starts, self.sizes, strict=True)]
        pos = torch.zeros(layout.n_tables, dtype=torch.long)
        pos[order] = torch.arange(len(order))
        prims = layout.groups[0]
        child_table = layout.table_children[order].clamp_min(0)
        for name, value in (
            ("order", order),
            ("node", layout.table_node[order]),
            ("child_table", child_table),
            ("child_valid", layout.table_child_valid[order]),
            ("inst_pos", pos[layout.inst_table]),
            ("prims", prims),
            ("prim_node", layout.table_node[prims]),
        ):
            self.register_buffer(name, value, persistent=False)
        self.register_buffer("cols", torch.arange(layout.max_children), persistent=False)
        for k, (start, end) in enumerate(self.bounds):
            self.register_buffer(f"group_ids_{k}", order[start:end].clone(), persistent=False)
            kids = child_table[start:end].reshape(-1).clone()
            self.register_buffer(f"group_children_{k}", kids, persistent=False)
        # the table position of every choosing instance (``graph.choosers``)
        chooser_pos = pos[layout.inst_table[graph.choosers]]
        self.register_buffer("chooser_pos", chooser_pos, persistent=False)
        self._offsets: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
        self._tabulated: dict[int, tuple] = {}
        self._bases: dict[tuple[int, int], tuple] = {}
        self._child_index: dict[int, list[torch.Tensor]] = {}
        self._penalties: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}
        self._by_learner: dict[tuple[int, int], tuple[torch.Tensor, torch.Tensor]] = {}
        self.n_tables = layout.n_tables

    @property
    def group_ids(self) -> list[torch.Tensor]:
        """Table ids of each height group, bottom-up."""
        return [self.get_buffer(f"group_ids_{k}") for k in range(len(self.bounds))]

    @property
    def group_children(self) -> list[torch.Tensor]:
        """Children's table ids of each height group, ``[G * A]`` (padding: 0)."""
        return [self.get_buffer(f"group_children_{k}") for k in range(len(self.bounds))]

    def offsets(self, bank: TableBank) -> tuple[torch.Tensor, torch.Tensor]:
        """``(offset [Tc], n_cols [Tc])`` of ``bank``'s blocks in plan order (cached)."""
        key = id(bank)
        cached = self._offsets.get(key)
        if cached is None or cached[0].device != self.order.device:
            cached = (bank.offset[self.order], bank.n_cols[self.order])
            self._offsets[key] = cached
        return cached

    def row_index(self, bank: TableBank, learner: torch.Tensor, state: torch.Tensor):
        """Flat indices ``[B, Tc, A]`` of the rows of every planned table.

        ``learner [B]``; ``state [B, Tc]`` the tables' abstract states.
        """
        offset, n_cols = self.offsets(bank)
        base = (learner * bank.stride)[:, None] + offset + state * n_cols
        return base[..., None] + self.cols

    def rows_at(self, ctx, bank: TableBank, penalty: bool = False):
        """``(blocked [B, Tc, A], dead [B, Tc], index [B, Tc, A])`` of the tables at ``ctx``.

        ``blocked``: the child is not available (padding slots are never available); ``index``
        holds the flat indices of the rows of ``bank``'s planned tables (read with ``take``;
        the entries of blocked children hold any finite value, read them only masked);
        ``dead``: the table's state is terminal for it, or no child is available. With
        ``penalty``, ``blocked`` comes as floats instead: -inf where blocked, 0 elsewhere
        (``q + penalty`` masks with one vectorised add; a ``masked_fill`` of a ``[B, G, A]``
        float tensor costs about ten times as much on the CPU).
        """
        per_state = self._per_state(bank) if ctx.table_row is not None else None
        if per_state is not None:
            blocked, dead, index = per_state
            blocked = self._penalty(blocked, keep=True) if penalty else blocked
            blocked, dead = (t.index_select(0, ctx.table_row) for t in (blocked, dead))
            return blocked, dead, self._index_at(bank, index, ctx)
        blocked = ~columns(ctx.available, self.node)
        dead = columns(ctx.blocked, self.node) | blocked.all(-1)
        index = self.row_index(bank, ctx.learner, columns(ctx.abstract, self.node))
        return (self._penalty(blocked) if penalty else blocked), dead, index

    def _index_at(self, bank: TableBank, index: torch.Tensor, ctx) -> torch.Tensor:
        """``index [S, Tc, A]`` (learner 0's, per state) at ``ctx``'s rows, for their learners.

        Up to ``TABULATE_LIMIT`` entries for all learners, the table is made for every
        (learner, state) once and read at ``learner * S + state``: one ``[B]`` add instead of
        a ``[B, Tc, A]`` one (the same indices).
        """
        n_states = index.shape[0]
        if bank.n_learners * index.numel() > self.TABULATE_LIMIT:
            picked = index.index_select(0, ctx.table_row)
            return picked + self.learner_base(ctx.learner, bank.stride, 3)
        key = (id(bank), id(index))
        cached = self._by_learner.get(key)
        if cached is None or cached[0] is not index:
            base = torch.arange(bank.n_learners, device=index.device) * bank.stride
            every = (base[:, None, None, None] + index).view(-1, *index.shape[1:])
            cached = self._by_learner[key] = (index, every)
        row = self.learner_base(ctx.learner, n_states, 1) + ctx.table_row
        return cached[1].index_select(0, row)

    def _penalty(self, blocked: torch.Tensor, keep: bool = False) -> torch.Tensor:
        """-inf where ``blocked``, 0 elsewhere; ``keep``: cached (a per-state table)."""
        cached = self._penalties.get(id(blocked)) if keep else None
        if cached is not None and cached[0] is blocked:
            return cached[1]
        out = torch.zeros(blocked.shape, device=blocked.device).masked_fill_(blocked, -torch.inf)
        if keep:
            self._penalties[id(blocked)] = (blocked, out)
        return out

    def child_index(self, batch: int) -> list[torch.Tensor]:
        """Per height group, where its tables' children are in a ``[B, T]`` value tensor.

        ``[B, G, A]`` flat indices for ``take`` (padding slots read child 0), kept per ``B``.
        """
        cached = self._child_index.get(batch)
        if cached is None or cached[0].device != self.order.device:
            rows = torch.arange(batch, device=self.order.device)[:, None, None] * self.n_tables
            cached = [rows + kids.view(-1, self.cols.shape[0]) for kids in self.group_children]
            self._child_index[batch] = cached
        return cached

    def learner_base(self, learner: torch.Tensor, stride: int, dims: int) -> torch.Tensor:
        """``learner * stride`` shaped ``[B, 1, ...]`` (``dims`` dimensions).

        Kept while the rows' learners are the same tensor (an executor's rows).
        """
        key = (stride, dims)
        cached = self._bases.get(key)
        if cached is None or cached[0] is not learner:
            cached = (learner, (learner * stride).view(-1, *([1] * (dims - 1))))
            self._bases[key] = cached
        return cached[1]

    def _per_state(self, bank: TableBank):
        """``rows_at``'s fields for every state of the tabulated graph (learner 0), cached."""
        g = self.graph
        key = (id(bank), id(g.tab_abstract), g.tab_abstract.device)
        if key not in self._tabulated:
            per_state = None
            if g.tab_abstract.shape[0] * self.child_table.numel() <= self.TABULATE_LIMIT:
                blocked = ~g.tab_available[:, self.node]
                dead = g.tab_blocked[:, self.node] | blocked.all(-1)
                offset, n_cols = self.offsets(bank)
                index = (offset + g.tab_abstract[:, self.node] * n_cols)[..., None] + self.cols
                per_state = (blocked, dead, index)
            self._tabulated[key] = per_state
        return self._tabulated[key]

    def prim_index_at(self, ctx, bank: TableBank) -> torch.Tensor:
        """Flat indices ``[B, Tp]`` of the primitive tables' entries of ``bank`` at ``ctx``."""
        if ctx.table_row is not None:
            g = self.graph
            key = (id(bank), "prims", id(g.tab_abstract), g.tab_abstract.device)
            per_state = self._tabulated.get(key)
            if per_state is None:
                state = g.tab_abstract[:, self.prim_node]
                offset, n_cols = bank.offset[self.prims], bank.n_cols[self.prims]
                per_state = offset + state * n_cols
                self._tabulated[key] = per_state
            base = self.learner_base(ctx.learner, bank.stride, 2)
            return per_state.index_select(0, ctx.table_row) + base
        state = columns(ctx.abstract, self.prim_node)
        return bank.index(ctx.learner[:, None], self.prims, state, 0)
