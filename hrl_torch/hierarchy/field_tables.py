"""Predicates looked up per node over the few discrete fields each one reads.

``TaskGraph.tabulate`` needs the whole state as one integer field. Most nodes of a larger
task read only a few discrete observation fields (an AGV's navigation subtask: its
location); their abstraction, termination, initiation and child mask are then functions of
those fields alone, and can be computed once for every combination of their values.
``FieldTables`` does that for the nodes it can, given each field's size (``[0, n)``, the env's
``observation_sizes``): it finds which fields a node's predicates read (by calling them once
on a sample with a recording view of the observation), groups the nodes by those fields, and
evaluates each group's predicates over the product of its fields' values. ``lookup`` then
gives every tabulated node's four predicates at a step with a few batched ops, whatever the
number of nodes: the per-node calls (a handful of ops each) are gone.

A node is left to its own calls (``TaskGraph.context`` as before) when it reads anything
else (a field without a size, the observation as a whole, its invocation memory), when its
fields' product exceeds ``limit`` or when a call fails on the sample or the grid. The values
are the predicates' own, so a step computes exactly what the calls computed; a field outside
its size makes every tabulated abstract state of its row -1, which the graph's range check
reports (naming the field).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from tensordict import TensorDict
from torch import nn

#: attributes of an observation a predicate may read without reading a field
_NEUTRAL = frozenset({"device", "batch_size", "shape"})


class _Unsupported(Exception):
    """A predicate read the observation in a way the recording view cannot follow."""


class _Reads:
    """An observation that records the fields read from it (``keys``)."""

    def __init__(self, td: TensorDict) -> None:
        self._td, self.keys = td, set()

    def __getitem__(self, key):
        if not isinstance(key, str):
            raise _Unsupported(key)
        self.keys.add(key)
        return self._td[key]

    def get(self, key, *default):
        """``td.get`` (recorded)."""
        return self[key] if key in self._td.keys() or not default else default[0]

    def __getattr__(self, name):
        if name in _NEUTRAL:
            return getattr(self._td, name)
        raise _Unsupported(name)


def _calls(graph, k: int, obs) -> list:
    """Node ``k``'s four predicates at ``obs`` (what ``TaskGraph.context`` would call)."""
    node = graph.nodes[k]
    out = [graph._abstract_of(obs, k)]
    if not node.is_primitive:
        out += [node.terminated(obs), node.initiable(obs), node.child_mask(obs)]
    return out


def fields_read(graph, k: int, sizes: Mapping[str, int]) -> tuple[str, ...] | None:
    """The sized fields node ``k``'s predicates read (sorted), or ``None``: not tabulable."""
    node = graph.nodes[k]
    if node.memory_size:
        return None
    gen = torch.Generator().manual_seed(k)
    sample = TensorDict(
        {f: torch.randint(0, n, (8,), generator=gen) for f, n in sizes.items()}, batch_size=[8]
    )
    reads = _Reads(sample)
    try:
        _calls(graph, k, reads)
    except Exception:  # (an unsupported read, or a field the sample lacks)
        return None
    return tuple(sorted(reads.keys))


def _grid(fields: tuple[str, ...], sizes: Mapping[str, int]) -> TensorDict:
    """Every combination of ``fields``' values, the first field varying slowest."""
    n = math.prod(sizes[f] for f in fields)
    index, columns = torch.arange(n), {}
    for f in reversed(fields):
        columns[f] = index % sizes[f]
        index = index // sizes[f]
    return TensorDict(columns, batch_size=[n])


class FieldTables(nn.Module):
    """Every tabulable node's predicates over its fields' values (see the module docstring).

    Buffers: ``nodes [Nt]`` the tabulated nodes; ``strides [F, G]`` each field's place value
    in each group's row (0 where the group does not read it); ``sizes [F]``; ``node_group
    [Nt]``, ``node_width [Nt]`` (the group's node count) and ``node_base [Nt]`` (where the
    node's column starts in the flat tables); the flat tables ``abstract``, ``terminated``,
    ``initiable`` ``[E + 1]`` and ``mask [E + 1, A]`` (entry ``base + row * width + j``; the
    last entry, read for a field out of range: abstract -1, nothing available).
    """

    def __init__(self, graph, sizes: Mapping[str, int], limit: int = 1 << 17) -> None:
        super().__init__()
        groups: dict[tuple[str, ...], list[int]] = {}
        for k in range(graph.n_nodes):
            if k not in graph.called_nodes:
                continue  # (its predicates are the defaults: constant columns)
            fields = fields_read(graph, k, sizes)
            if fields is not None and math.prod(sizes[f] for f in fields) <= limit:
                groups.setdefault(fields, []).append(k)
        tables: list[list[torch.Tensor]] = [[], [], [], []]
        nodes, node_group, node_width, node_base = [], [], [], []
        kept: list[tuple[str, ...]] = []
        base = 0
        for fields, members in groups.items():
            columns = self._evaluate(graph, members, _grid(fields, sizes))
            if columns is None:
                continue
            for j, k in enumerate(members):
                nodes.append(k)
                node_group.append(len(kept))
                node_width.append(len(members))
                node_base.append(base + j)
            for out, values in zip(tables, columns, strict=True):
                out.append(values.reshape(-1, *values.shape[2:]))
            base += columns[0].numel()
            kept.append(fields)
        self.fields = sorted({f for fields in kept for f in fields})
        strides = torch.zeros(len(self.fields), max(len(kept), 1), dtype=torch.long)
        for g, fields in enumerate(kept):
            place = 1
            for f in reversed(fields):
                strides[self.fields.index(f), g] = place
                place *= sizes[f]
        self.n_tabulated = len(nodes)
        long = dict(dtype=torch.long)
        a = graph.max_children
        false = torch.zeros(1, dtype=torch.bool)
        sentinel = (torch.full((1,), -1, **long), false, false, torch.zeros(1, a, dtype=torch.bool))
        for name, value in (
            ("nodes", torch.tensor(nodes, **long)),
            ("strides", strides),
            ("sizes", torch.tensor([sizes[f] for f in self.fields], **long)),
            ("node_group", torch.tensor(node_group, **long)),
            ("node_width", torch.tensor(node_width, **long)),
            ("node_base", torch.tensor(node_base, **long)),
        ):
            self.register_buffer(name, value, persistent=False)
        for name, parts, end in zip(
            ("abstract", "terminated", "initiable", "mask"), tables, sentinel, strict=True
        ):
            self.register_buffer(name, torch.cat([*parts, end]), persistent=False)

    @staticmethod
    def _evaluate(graph, members: list[int], grid: TensorDict):
        """``[R, n]`` abstract, terminated, initiable and ``[R, n, A]`` masks of ``members``."""
        r, a = grid.batch_size[0], graph.max_children
        abstract = torch.zeros(r, len(members), dtype=torch.long)
        terminated = torch.zeros(r, len(members), dtype=torch.bool)
        initiable = torch.ones(r, len(members), dtype=torch.bool)
        mask = torch.ones(r, len(members), a, dtype=torch.bool)
        try:
            for j, k in enumerate(members):
                values = _calls(graph, k, grid)
                if any(v is not None and v.shape[0] != r for v in values):
                    return None
                abstract[:, j] = values[0]
                if len(values) > 1:  # (a primitive has only its abstract state)
                    terminated[:, j], initiable[:, j] = values[1], values[2]
                    if values[3] is not None:
                        mask[:, j, : values[3].shape[1]] = values[3].bool()
        except Exception:  # (a wrong shape, a predicate failing on a grid's combination)
            return None
        return abstract, terminated, initiable, mask

    def entries(self, obs: TensorDict) -> torch.Tensor:
        """``[B, Nt]``: each tabulated node's entry in the flat tables at ``obs``."""
        values = torch.stack([obs[f] for f in self.fields], 1).long()  # [B, F]
        row = (values[:, :, None] * self.strides).sum(1)  # [B, G]
        entry = row.index_select(1, self.node_group) * self.node_width + self.node_base
        outside = ((values < 0) | (values >= self.sizes)).any(1, keepdim=True)
        return entry.masked_fill_(outside, self.abstract.shape[0] - 1)

    def lookup(self, obs: TensorDict):
        """``(abstract, terminated, initiable [B, Nt], mask [B, Nt, A])`` at ``obs``."""
        entry = self.entries(obs)
        b = entry.shape[0]
        mask = self.mask.index_select(0, entry.view(-1)).view(b, self.n_tabulated, -1)
        return (torch.take(self.abstract, entry), torch.take(self.terminated, entry),
                torch.take(self.initiable, entry), mask)  # fmt: skip

    def field_outside(self, obs: TensorDict, row: int) -> str | None:
        """The first field of ``obs``'s row ``row`` outside its size (for an error)."""
        for f, n in zip(self.fields, self.sizes.tolist(), strict=True):
            v = int(obs[f][row])
            if not 0 <= v < n:
                return f"observation field {f!r} is {v} in env row {row}, outside [0, {n})"
        return None


#: a lookup costs about the ops of this many predicate calls: fewer are left as calls
MIN_CALLS = 16


def tabulate_fields(graph, sizes: Mapping[str, int], limit: int = 1 << 17) -> int:
    """Look up the predicates of ``graph``'s nodes that read only sized fields; how many.

    ``TaskGraph.tabulate_fields``. ``sizes``: discrete observation fields and their sizes
    (values in ``[0, n)``, e.g. an env's ``observation_sizes``). A node whose predicates read
    only such fields, with at most ``limit`` combinations of their values, is evaluated once
    over all of them; ``context`` then looks its abstract state, termination, initiation and
    child mask up instead of calling them: the same values. The other nodes are called as
    before. Fewer than ``MIN_CALLS`` calls saved are not worth a lookup: nothing changes.
    Idempotent; a graph tabulated by state (``TaskGraph.tabulate``) is left alone.
    """
    if graph.table_key is not None or graph.field_tables is not None:
        return 0 if graph.field_tables is None else graph.field_tables.n_tabulated
    tables = FieldTables(graph, sizes, limit)
    done = set(tables.nodes.tolist())
    names = ("_abstract_nodes", "_terminating_nodes", "_initiable_nodes")
    lists = [getattr(graph, name) for name in names]
    calls = sum(len(done & set(x[0])) for x in lists) + len(done & set(graph._mask_nodes))
    if calls < MIN_CALLS:
        return 0
    graph.field_tables = tables.to(graph.node_children.device)
    for name, nodes in zip(names, lists, strict=True):
        kept = [k for k in nodes[0] if k not in done]
        setattr(graph, name, (kept, nodes[1], torch.tensor(kept, dtype=torch.long)))
    graph._mask_nodes = [k for k in graph._mask_nodes if k not in done]
    return tables.n_tabulated
