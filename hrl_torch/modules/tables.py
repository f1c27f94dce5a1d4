"""Tensor tables for a population of tabular learners.

A ``TableBank`` keeps one kind of table (completion ``C``, primitive values ``V``, ...) for every
table node of a hierarchy in one flat buffer of shape ``[P, total]``: node ``t`` owns the block
``offset[t] : offset[t] + n_states[t] * n_cols[t]``. One flat buffer lets a whole batch of
transitions, from any mix of nodes and learners, be read with one ``gather`` and written with one
``put_``. ``TableLayout`` says which table node serves which executor instance: one table per
subtask for recursively optimal learners, one per instance (per Task-Stack context) for
hierarchically optimal ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from hrl_torch.common.devices import MovesTensorAttrs
from hrl_torch.common.ops import group_of_rows, lookup, take_flat
from hrl_torch.common.per_learner import at_entries, check_size, is_per_learner
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.modules.schedules import VisitCount


@dataclass(frozen=True)
class RowSteps:
    """A step size per row of an update (shaped like its ``flat_index``), e.g. ``1 / visits``."""

    alpha: torch.Tensor


class TableLayout(MovesTensorAttrs, nn.Module):
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


class _FlatStore(MovesTensorAttrs, nn.Module):
    """A flat float buffer ``store`` of tables, with its same-step update rule.

    ``store`` holds ``P * stride`` entries (learner ``p``'s block first at ``p * stride``)
    followed by one *sentinel* entry that stays 0: reads and writes of masked rows are aimed
    at it, so a masked read is a single ``index_select``. ``pad`` more zeros may follow, so
    that a whole row of width ``pad`` read from any table stays inside the store.
    """

    #: above this many entries, same-step updates are grouped with ``unique`` (no scratch)
    SCRATCH_LIMIT = 1 << 22

    def _init_store(
        self, n_learners: int, stride: int, fill: torch.Tensor, pad: int = 0, visits: bool = False
    ) -> None:
        """A store of ``fill``: one learner's block ``[stride]`` or each one's ``[P, stride]``.

        ``visits``: also count each entry's updates (``visits``, shaped like ``store``), for
        the per-entry step size ``VisitCount``.
        """
        self.n_learners, self.stride, self.pad = n_learners, stride, pad
        self.sentinel = n_learners * stride
        blocks = fill.expand(n_learners, stride).reshape(-1)
        store = torch.cat([blocks, torch.zeros(1 + pad)])
        self.register_buffer("store", store)
        self.counts_visits = visits
        if visits:
            self.register_buffer("visits", torch.zeros_like(store))
        self._scratch = torch.zeros(2, 0)

    def update(
        self,
        flat_index: torch.Tensor,
        target: torch.Tensor,
        alpha: torch.Tensor | float | RowSteps,
        mask: torch.Tensor,
        distinct: bool = False,
    ) -> torch.Tensor:
        """Move entries toward their targets: ``W <- (1-a)^n W + (1-(1-a)^n) mean(target)``.

        Every entry hit by ``n`` rows in this batch takes the ``n`` same-step updates at once,
        order-free (exact when the targets agree). Rows with ``mask`` False change nothing.
        Shapes: ``flat_index``, ``target``, ``mask`` of one shape (each element a row);
        ``alpha`` a number or a per-learner tensor ``[P]`` (``hrl_torch.common.per_learner``: an
        entry of learner ``p`` moves with ``alpha[p]``), or ``RowSteps`` (row ``i`` moves with
        its own ``alpha.alpha[i]``). Returns each row's entry before the
        update (0 for masked rows), in that shape.

        ``distinct``: the caller knows that no two unmasked rows hit one entry (each row of
        its batch belongs to another learner, and one row's entries differ), so ``n <= 1``
        and the rule is the plain ``W <- W + a (target - W)``, the same numbers in fewer ops.

        ``alpha`` a ``VisitCount``: each entry's own ``alpha_n = clip(1/n, low, high)`` from
        its count of updates (a store made with ``visits``); ``n`` same-step hits keep
        ``prod (1 - alpha_n)`` of ``W`` over their ``n`` counts (``VisitCount.keep``).
        """
        flat = self.store
        index = flat_index.masked_fill(~mask, self.sentinel)  # masked rows hit the sentinel
        if isinstance(alpha, VisitCount):
            return self._update_by_visits(index, target, alpha, mask, distinct)
        if isinstance(alpha, RowSteps):
            rho = 1.0 - alpha.alpha
        else:
            rho = at_entries(1.0 - alpha, index, self.stride, flat.dtype)  # 1 - alpha of each row
        if distinct:
            old = take_flat(flat, index)
            mean = torch.nan_to_num(target)
            new = mean + rho * (old - mean)  # (the n = 1 case below, op for op)
            flat.put_(index, torch.where(mask, new, old))  # (``put_``: flat, cheaper)
            return old
        shape = index.shape
        index, target, mask = index.reshape(-1), target.reshape(-1), mask.reshape(-1)
        if isinstance(rho, torch.Tensor):
            rho = rho.reshape(-1)
        weight = mask.to(flat.dtype)
        weighted = torch.stack([weight, torch.nan_to_num(target)]) * weight
        n, total = self._count_and_sum(index, weighted)
        keep = rho**n  # (1 - alpha)^n; n = 0 keeps W (and the sentinel 0)
        mean = total / n.clamp_min(1.0)
        old = flat.index_select(0, index)
        flat.put_(index, mean + keep * (old - mean))
        return old.view(shape)

    def count_visits(self) -> None:
        """Start counting each entry's updates (``visits``, zero now) for ``VisitCount``."""
        if not self.counts_visits:
            self.register_buffer("visits", torch.zeros_like(self.store))
            self.counts_visits = True
        for bank in getattr(self, "banks", {}).values():
            bank.counts_visits = True

    def _update_by_visits(self, index, target, steps: VisitCount, mask, distinct: bool):
        """``update`` with the per-entry step size ``steps`` (masked rows' ``index``: sentinel).

        The counts move with the entries: an entry hit by ``m`` rows counts ``m`` more.
        """
        if not self.counts_visits:
            raise ValueError(
                f"{type(self).__name__}: a VisitCount step size needs tables that count visits "
                "(a tabular learner's banks made with alpha=VisitCount(...)); these do not"
            )
        flat, visits = self.store, self.visits
        if distinct:  # (each unmasked row its own entry: m = 1)
            old, before = take_flat(flat, index), take_flat(visits, index)
            hits = mask.to(flat.dtype)
            mean = torch.nan_to_num(target)
            new = mean + steps.keep(before, hits) * (old - mean)
            flat.put_(index, torch.where(mask, new, old))
            visits.put_(index, before + hits)
            return old
        shape = index.shape
        index, target, mask = index.reshape(-1), target.reshape(-1), mask.reshape(-1)
        weight = mask.to(flat.dtype)
        weighted = torch.stack([weight, torch.nan_to_num(target)]) * weight
        n, total = self._count_and_sum(index, weighted)
        before = visits.index_select(0, index)
        keep = steps.keep(before, n)  # n = 0 (masked rows, the sentinel) keeps W
        mean = total / n.clamp_min(1.0)
        old = flat.index_select(0, index)
        flat.put_(index, mean + keep * (old - mean))
        visits.put_(index, before + n)
        return old.view(shape)

    def _count_and_sum(self, index, weighted) -> tuple[torch.Tensor, torch.Tensor]:
        """Per row: how many rows hit its entry, and the sum of their values (order-free).

        ``weighted [2, R]``: each row's weight (1, or 0 for masked rows) and weighted value.
        Small tables use a scratch buffer twice the table's size (no sort, no sync); large
        ones (flat learners on big state spaces) group the rows with ``unique`` instead.
        """
        if self.store.numel() > self.SCRATCH_LIMIT:
            group = group_of_rows(index)
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
        init: initial value of every entry (a number, or one per learner: a tensor ``[P]``).
        pad: zeros after the sentinel (``_FlatStore``).
        visits: count each entry's updates (for the step size ``VisitCount``).
    """

    def __init__(
        self,
        n_learners: int,
        n_states: torch.Tensor,
        n_cols: torch.Tensor,
        init: float | torch.Tensor = 0.0,
        pad: int = 0,
        visits: bool = False,
    ) -> None:
        super().__init__()
        sizes = n_states.long() * n_cols.long()
        offset = torch.cumsum(sizes, 0) - sizes
        self.total = max(int(sizes.sum()), 1)
        check_size(self, "init", init, n_learners)
        self.init = init if is_per_learner(init) else float(init)
        self.register_buffer("offset", offset, persistent=False)
        self.register_buffer("n_cols", n_cols.long(), persistent=False)
        self._blocks = list(zip(offset.tolist(), n_states.tolist(), n_cols.tolist(), strict=True))
        self._set: TableSet | None = None
        self.base = 0
        fill = self.init.float()[:, None] if is_per_learner(self.init) else self.init
        self._init_store(n_learners, self.total, torch.zeros(self.total) + fill, pad, visits)

    def _join(self, tables: TableSet, base: int) -> None:
        """Keep this bank's entries in ``tables``' store, from ``base`` in each learner block."""
        del self._buffers["store"]
        self._buffers.pop("visits", None)  # (counted in the set's, if it counts)
        self.counts_visits = tables.counts_visits
        object.__setattr__(self, "_set", tables)  # the set owns the bank, not the reverse
        self.base = base
        self.offset += base
        self._blocks = [(start + base, n, c) for start, n, c in self._blocks]
        self.stride, self.sentinel = tables.stride, tables.sentinel

    def __getattr__(self, name: str):
        if name in ("store", "visits") and self.__dict__.get("_set") is not None:
            return getattr(self._set, name)
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
        fills = [bank.data for bank in banks.values()]  # every learner's block
        stride, pad = sum(b.total for b in banks.values()), max(b.pad for b in banks.values())
        visits = any(bank.counts_visits for bank in banks.values())
        self._init_store(first.n_learners, stride, torch.cat(fills, 1), pad, visits)
        self.banks = nn.ModuleDict(banks)
        start = 0
        for bank in banks.values():
            bank._join(self, start)
            start += bank.total
