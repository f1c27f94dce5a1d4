"""Tensor tables for a population of tabular learners.

A ``TableBank`` keeps one kind of table (completion ``C``, primitive values ``V``, ...) for every
table node of a hierarchy in one flat buffer of shape ``[P, total]``: node ``t`` owns the block
``offset[t] : offset[t] + n_states[t] * n_cols[t]``. One flat buffer lets a whole batch of
transitions, from any mix of nodes and learners, be read with one ``gather`` and written with one
``index_put_``. ``TableLayout`` says which table node serves which executor instance: one table per
subtask for recursively optimal learners, one per instance (per Task-Stack context) for
hierarchically optimal ones.
"""

from __future__ import annotations

import torch
from torch import nn

from hrl_torch.graph import TaskGraph
from hrl_torch.ops import columns, lookup


class TableLayout(nn.Module):
    """Table nodes of a learner over a task graph.

    Args:
        graph: the compiled task graph.
        per_instance: one table per instance (hierarchical optimality) instead of per subtask.

    Attributes (buffers): ``table_node [T]`` graph node of each table, ``table_children [T, A]``
    table ids of the children (-1 padding), ``inst_table [I]`` table of each instance, and
    ``groups``: table ids grouped by height, leaves first, for bottom-up evaluation.
    """

    def __init__(self, graph: TaskGraph, per_instance: bool) -> None:
        super().__init__()
        self.per_instance = per_instance
        if per_instance:
            table_node = graph.inst_node.clone()
            table_children = graph.inst_children.clone()
            inst_table = torch.arange(graph.n_instances)
        else:
            table_node = torch.arange(graph.n_nodes)
            table_children = graph.node_children.clone()
            inst_table = graph.inst_node.clone()
        self.register_buffer("table_node", table_node, persistent=False)
        self.register_buffer("table_children", table_children, persistent=False)
        self.register_buffer("inst_table", inst_table, persistent=False)
        self.register_buffer(
            "table_is_primitive", graph.node_is_primitive[table_node], persistent=False
        )
        self.register_buffer("table_n_states", graph.node_n_states[table_node], persistent=False)
        self.register_buffer(
            "table_n_children", graph.node_n_children[table_node], persistent=False
        )
        self.register_buffer("table_child_valid", table_children >= 0, persistent=False)
        height = graph.node_height[table_node]
        self.groups = [(height == h).nonzero().squeeze(1) for h in range(int(height.max()) + 1)]
        self.n_tables = int(table_node.shape[0])
        self.max_children = graph.max_children

    def composite_ids(self) -> torch.Tensor:
        """Ids of the non-primitive tables."""
        return (~self.table_is_primitive).nonzero().squeeze(1)

    def primitive_ids(self) -> torch.Tensor:
        """Ids of the primitive tables."""
        return self.table_is_primitive.nonzero().squeeze(1)


class _FlatStore(nn.Module):
    """A flat float buffer ``store`` of tables, with its same-step update rule.

    ``store`` holds ``P * stride`` entries (learner ``p``'s block first at ``p * stride``)
    followed by one *sentinel* entry that stays 0: reads and writes of masked rows are aimed
    at it, so a masked read is a single ``index_select``. ``pad`` more zeros may follow, so
    that a whole row of width ``pad`` read from any table stays inside the store.
    """

    #: above this many entries, same-step updates are grouped with ``unique`` (no scratch)
    SCRATCH_LIMIT = 1 << 22

    def _init_store(self, n_learners: int, stride: int, fill: torch.Tensor, pad: int = 0) -> None:
        self.n_learners, self.stride, self.pad = n_learners, stride, pad
        self.sentinel = n_learners * stride
        store = torch.cat([fill.repeat(n_learners), torch.zeros(1 + pad)])
        self.register_buffer("store", store)
        self._scratch = torch.zeros(2, 0)

    def update(
        self,
        flat_index: torch.Tensor,
        target: torch.Tensor,
        alpha: torch.Tensor | float,
        mask: torch.Tensor,
        distinct: bool = False,
    ) -> torch.Tensor:
        """Move entries toward their targets: ``W <- (1-a)^n W + (1-(1-a)^n) mean(target)``.

        Every entry hit by ``n`` rows in this batch takes the ``n`` same-step updates at once,
        order-free (exact when the targets agree). Rows with ``mask`` False change nothing.
        Shapes: ``flat_index``, ``target``, ``mask`` of one shape (each element a row);
        ``alpha`` scalar or that shape. Returns each row's entry before the update (0 for
        masked rows), in that shape.

        ``distinct``: the caller knows that no two unmasked rows hit one entry (each row of
        its batch belongs to another learner, and one row's entries differ), so ``n <= 1``
        and the rule is the plain ``W <- W + a (target - W)``, the same numbers in fewer ops.
        """
        flat = self.store
        index = flat_index.masked_fill(~mask, self.sentinel)  # masked rows hit the sentinel
        if distinct:
            old = torch.take(flat, index)
            mean = torch.nan_to_num(target)
            new = mean + (1.0 - alpha) * (old - mean)  # (the n = 1 case below, op for op)
            flat.index_put_((index,), torch.where(mask, new, old))
            return old
        shape = index.shape
        index, target, mask = index.reshape(-1), target.reshape(-1), mask.reshape(-1)
        if isinstance(alpha, torch.Tensor) and alpha.dim():
            alpha = alpha.reshape(-1)
        weight = mask.to(flat.dtype)
        weighted = torch.stack([weight, torch.nan_to_num(target)]) * weight
        n, total = self._count_and_sum(index, weighted)
        keep = (1.0 - alpha) ** n  # rho = (1 - alpha)^n; n = 0 keeps W (and the sentinel 0)
        mean = total / n.clamp_min(1.0)
        old = flat.index_select(0, index)
        flat.index_put_((index,), mean + keep * (old - mean))
        return old.view(shape)

    def _count_and_sum(self, index, weighted) -> tuple[torch.Tensor, torch.Tensor]:
        """Per row: how many rows hit its entry, and the sum of their values (order-free).

        ``weighted [2, R]``: each row's weight (1, or 0 for masked rows) and weighted value.
        Small tables use a scratch buffer twice the table's size (no sort, no sync); large
        ones (flat learners on big state spaces) group the rows with ``unique`` instead.
        """
        if self.store.numel() > self.SCRATCH_LIMIT:
            _, group = torch.unique(index, return_inverse=True)
            sums = torch.zeros_like(weighted).index_add_(1, group, weighted)
            n, total = sums.index_select(1, group)
            return n, total
        if self._scratch.shape[1] != self.store.shape[0] or self._scratch.device != index.device:
            self._scratch = torch.zeros(2, self.store.shape[0], device=self.store.device)
        self._scratch.index_add_(1, index, weighted)
        n, total = self._scratch.index_select(1, index)
        self._scratch.index_fill_(1, index, 0.0)
        return n, total

    @property
    def save_store(self) -> bool:
        """Whether ``store`` is in the state dict (False when heads save views of it)."""
        return "store" not in self._non_persistent_buffers_set

    @save_store.setter
    def save_store(self, value: bool) -> None:
        if value:
            self._non_persistent_buffers_set.discard("store")
        else:
            self._non_persistent_buffers_set.add("store")


class TableBank(_FlatStore):
    """One kind of table for all table nodes and all ``P`` learners, stored flat.

    Node ``t`` of learner ``p`` owns the entries ``p * stride + offset[t]`` onward
    (``n_states[t] * n_cols[t]`` of them, row-major). A bank made by ``TableSet`` shares the
    set's store with the set's other kinds (``stride`` then counts every kind's entries and
    ``offset`` includes the bank's place in the learner's block); a plain bank has its own
    (``stride == total``).

    Args:
        n_learners: population size ``P``.
        n_states: abstract states per table node ``[T]`` (0 for nodes without this table).
        n_cols: columns per table node ``[T]`` (children for completion tables, 1 for values).
        init: initial value of every entry.
        pad: zeros after the sentinel (``_FlatStore``).
    """

    def __init__(
        self,
        n_learners: int,
        n_states: torch.Tensor,
        n_cols: torch.Tensor,
        init: float = 0.0,
        pad: int = 0,
    ) -> None:
        super().__init__()
        sizes = n_states.long() * n_cols.long()
        offset = torch.cumsum(sizes, 0) - sizes
        self.total = max(int(sizes.sum()), 1)
        self.init = float(init)
        self.register_buffer("offset", offset, persistent=False)
        self.register_buffer("n_cols", n_cols.long(), persistent=False)
        self._blocks = list(zip(offset.tolist(), n_states.tolist(), n_cols.tolist(), strict=True))
        self._set: TableSet | None = None
        self.base = 0
        self._init_store(n_learners, self.total, torch.full((self.total,), self.init), pad)

    def _join(self, tables: TableSet, base: int) -> None:
        """Keep this bank's entries in ``tables``' store, from ``base`` in each learner block."""
        del self._buffers["store"]
        object.__setattr__(self, "_set", tables)  # the set owns the bank, not the reverse
        self.base = base
        self.offset += base
        self._blocks = [(start + base, n, c) for start, n, c in self._blocks]
        self.stride, self.sentinel = tables.stride, tables.sentinel

    def __getattr__(self, name: str):
        if name == "store" and self.__dict__.get("_set") is not None:
            return self._set.store
        return super().__getattr__(name)

    @property
    def save_store(self) -> bool:
        """Whether the store is in the state dict (the set's, when shared)."""
        if self._set is not None:
            return self._set.save_store
        return _FlatStore.save_store.fget(self)

    @save_store.setter
    def save_store(self, value: bool) -> None:
        _FlatStore.save_store.fset(self._set if self._set is not None else self, value)

    def update(self, flat_index, target, alpha, mask, distinct: bool = False) -> torch.Tensor:
        """``_FlatStore.update`` on this bank's store (the set's, when shared)."""
        if self._set is not None:
            return self._set.update(flat_index, target, alpha, mask, distinct)
        return super().update(flat_index, target, alpha, mask, distinct)

    @property
    def data(self) -> torch.Tensor:
        """The tables as ``[P, total]`` (a view of ``store``)."""
        rows = self.store[: self.sentinel].view(self.n_learners, self.stride)
        return rows[:, self.base : self.base + self.total]

    def index(
        self, learner: torch.Tensor, table: torch.Tensor, state: torch.Tensor, col: torch.Tensor
    ) -> torch.Tensor:
        """Flat indices into ``store``; all arguments broadcast together."""
        offset, n_cols = lookup(self.offset, table), lookup(self.n_cols, table)
        return learner * self.stride + offset + state * n_cols + col

    def row_index(
        self, learner: torch.Tensor, table: torch.Tensor, state: torch.Tensor, width: int
    ) -> torch.Tensor:
        """Flat indices of whole rows: shape ``learner.shape + (width,)``."""
        cols = torch.arange(width, device=self.store.device)
        offset, n_cols = lookup(self.offset, table), lookup(self.n_cols, table)
        base = learner * self.stride + offset + state * n_cols
        return base.unsqueeze(-1) + cols

    def read(self, flat_index: torch.Tensor, valid: torch.Tensor | None = None) -> torch.Tensor:
        """Values at flat indices; entries where ``valid`` is False read as 0."""
        if valid is not None:
            flat_index = torch.where(valid, flat_index, self.sentinel)
        return self.store.index_select(0, flat_index.reshape(-1)).view(flat_index.shape)

    def block(self, table: int) -> torch.Tensor:
        """The ``[P, n_states, n_cols]`` tables of one node for every learner (a view)."""
        start, n_states, n_cols = self._blocks[table]
        rows = self.store[: self.sentinel].view(self.n_learners, self.stride)
        return rows[:, start : start + n_states * n_cols].view(self.n_learners, n_states, n_cols)

    def view(self, table: int, learner: int = 0) -> torch.Tensor:
        """The ``[n_states, n_cols]`` table of one node and learner (a view, for inspection)."""
        return self.block(table)[learner]


class TableSet(_FlatStore):
    """Several banks of one learner in one store, so one ``update`` writes any mix of them.

    Learner ``p``'s block holds every bank's entries one after the other; a bank's flat
    indices are valid indices of the set's store, so the rows of a batch aimed at different
    banks (``C`` of the finished children and ``V`` of the primitive, say) are one update.
    The banks are this module's children (``tables.C``, ...); the learner keeps them as
    attributes too.

    Args:
        banks: the banks by name, each made alone first (their ``init`` is kept).
    """

    def __init__(self, **banks: TableBank) -> None:
        super().__init__()
        first = next(iter(banks.values()))
        fills = [bank.store[: bank.total] for bank in banks.values()]  # one learner's block
        stride, pad = sum(b.total for b in banks.values()), max(b.pad for b in banks.values())
        self._init_store(first.n_learners, stride, torch.cat(fills), pad)
        self.banks = nn.ModuleDict(banks)
        start = 0
        for bank in banks.values():
            bank._join(self, start)
            start += bank.total


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
        self.n_tables = layout.n_tables

    @property
    def group_ids(self) -> list[torch.Tensor]:
        """Table ids of each height group, bottom-up."""
        return [getattr(self, f"group_ids_{k}") for k in range(len(self.bounds))]

    @property
    def group_children(self) -> list[torch.Tensor]:
        """Children's table ids of each height group, ``[G * A]`` (padding: 0)."""
        return [getattr(self, f"group_children_{k}") for k in range(len(self.bounds))]

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

    def rows_at(self, ctx, bank: TableBank):
        """``(blocked [B, Tc, A], dead [B, Tc], index [B, Tc, A])`` of the tables at ``ctx``.

        ``blocked``: the child is not available (padding slots are never available); ``index``
        holds the flat indices of the rows of ``bank``'s planned tables (read with ``take``;
        the entries of blocked children hold any finite value, read them only masked);
        ``dead``: the table's state is terminal for it, or no child is available.
        """
        per_state = self._per_state(bank) if ctx.table_row is not None else None
        if per_state is not None:
            blocked, dead, index = (t.index_select(0, ctx.table_row) for t in per_state)
            return blocked, dead, index + self.learner_base(ctx.learner, bank.stride, 3)
        blocked = ~columns(ctx.available, self.node)
        dead = columns(ctx.blocked, self.node) | blocked.all(-1)
        index = self.row_index(bank, ctx.learner, columns(ctx.abstract, self.node))
        return blocked, dead, index

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
