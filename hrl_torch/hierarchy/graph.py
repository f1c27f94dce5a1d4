"""Task graphs: the compiled instance tree of a hierarchy, and its per-step context.

The nodes (``Subtask``, ``Primitive``; Definition 3.1) are defined in
``hrl_torch.hierarchy.subtask`` and re-exported here; validation and compilation are in
``hrl_torch.hierarchy.graph_compile``.

Subtasks form a DAG; one subtask may be shared by several parents. ``TaskGraph`` validates the
DAG and unrolls it into a tree of *instances*, one per path from the root: the executor runs
instances, hierarchically optimal learners index their tables by instance (the Task-Stack is
part of their state, Section 3.4) and recursively optimal learners by subtask.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
from tensordict import TensorDict
from torch import nn

from hrl_torch.common.devices import KeepsHostCopies, defined_at, same_device
from hrl_torch.common.ops import columns, lookup
from hrl_torch.hierarchy.field_tables import FieldTables, tabulate_fields
from hrl_torch.hierarchy.graph_compile import compile_instances, compile_nodes, validate
from hrl_torch.hierarchy.subtask import (  # noqa: F401  (Subtask, Primitive, GraphError: re-exported)
    GraphError,
    Node,
    ObsFn,
    Primitive,
    Subtask,
    batch_and_device,
    overrides,
)


@dataclass
class StepContext:
    """What the graph knows about one batch of observations, computed once per step.

    Shapes: ``learner`` ``[B]`` (learner of each row), ``abstract`` ``[B, n_nodes]`` long,
    ``terminated`` ``[B, n_nodes]`` bool (the predicate: ends a running invocation),
    ``blocked`` ``[B, n_nodes]`` bool (a terminal *state*: the node can neither start nor has
    value here; ``terminated`` without the event-terminated nodes),
    ``available`` ``[B, n_nodes, max_children]`` bool, ``features``
    ``[B, n_nodes, max_features]`` float (``None`` when no node has features); ``table_row``
    ``[B]`` the row of each observation in a tabulated graph's tables (``None`` otherwise),
    so that learners can look up their own per-state tables too.
    Learners add their own per-node values to ``values`` (e.g. ``V`` ``[B, n_tables]``).
    """

    obs: TensorDict
    learner: torch.Tensor
    abstract: torch.Tensor
    terminated: torch.Tensor
    blocked: torch.Tensor
    available: torch.Tensor
    features: torch.Tensor | None = None
    values: dict[str, torch.Tensor] = field(default_factory=dict)
    table_row: torch.Tensor | None = None


class TaskGraph(KeepsHostCopies, nn.Module):
    """A validated task DAG and its unrolled instance tree.

    Args:
        root: name of the root subtask.
        nodes: every subtask and primitive of the hierarchy.
        n_actions: size of the env's discrete action space; primitives outside it are an error.
        max_instances: guard against DAGs whose unrolled tree would be huge.
    """

    def __init__(
        self,
        root: str,
        nodes: Sequence[Node],
        n_actions: int | None = None,
        max_instances: int = 100_000,
    ) -> None:
        super().__init__()
        validate(root, nodes, n_actions)
        self.nodes = nn.ModuleList(nodes)
        self.names = [n.name for n in nodes]
        self.index = {name: k for k, name in enumerate(self.names)}
        self.root_name = root
        self.n_actions = n_actions
        # tensors of the node graph, of its unrolled instance tree, and per-node capabilities
        compile_nodes(self)
        compile_instances(self, max_instances)
        self._compile_capabilities()

    def _compile_capabilities(self) -> None:
        """Which nodes have internal rewards, custom predicates, features and memory."""
        self.internal_nodes = [k for k, x in enumerate(self.nodes) if x.has_internal_rewards()]
        self.shaping_nodes = [
            k for k, x in enumerate(self.nodes) if not x.is_primitive and x.has_shaping_rewards()
        ]
        self.check_ranges = True
        self._table_key: str | None = None  # set by ``tabulate``
        self.table_observations: TensorDict | None = None  # (``tabulate``'s observations)
        self.never_stuck = False  # (``tabulate`` can prove it)
        # which nodes need a call per step (defaults are constant columns)
        self._abstract_nodes = self._custom(lambda x: x.n_states > 1 or overrides(x, "abstract"))
        self._terminating_nodes = self._custom(
            lambda x: not x.is_primitive and overrides(x, "terminated")
        )
        self._initiable_nodes = self._custom(
            lambda x: not x.is_primitive and overrides(x, "initiable")
        )
        self._mask_nodes = [
            k for k, x in enumerate(self.nodes) if not x.is_primitive and overrides(x, "child_mask")
        ]
        #: nodes whose predicates ``context`` calls (the others' are constant columns)
        self.called_nodes = {
            *self._abstract_nodes[0], *self._terminating_nodes[0], *self._initiable_nodes[0],
            *self._mask_nodes,
        }  # fmt: skip
        self.field_tables: FieldTables | None = None  # (``field_tables.tabulate_fields``)
        self.action_dim = max((x.action_dim for x in self.nodes if x.is_primitive), default=0)
        self.feature_nodes = [k for k, x in enumerate(self.nodes) if x.n_features]
        self.max_features = max((x.n_features for x in self.nodes), default=0)
        self.memory_nodes = [k for k, x in enumerate(self.nodes) if x.memory_size]
        self.memory_feature_nodes = [k for k in self.memory_nodes if self.nodes[k].n_features]
        self.max_memory = max((x.memory_size for x in self.nodes), default=0)

    def _custom(self, pred) -> tuple[list[int], list[int], torch.Tensor]:
        """(node indices where ``pred`` holds, all node indices, the first as a tensor)."""
        ks = [k for k, x in enumerate(self.nodes) if pred(x)]
        return ks, list(range(self.n_nodes)), torch.tensor(ks, dtype=torch.long)

    # ------------------------------------------------------------------ helpers
    @property
    def root(self) -> int:
        """Node index of the root subtask (instance 0 is its only instance)."""
        return self.index[self.root_name]

    def node(self, name: str) -> Node:
        """The node with this name."""
        return self.nodes[self.index[name]]

    def instance_path(self, inst: int) -> str:
        """``Root/Get/Navigate_R`` style name of an instance."""
        parts = []
        while inst >= 0:
            parts.append(self.names[int(self.inst_node[inst])])
            inst = int(self.inst_parent[inst])
        return "/".join(reversed(parts))

    def subtasks(self) -> list[int]:
        """Indices of the non-primitive nodes."""
        return [k for k, x in enumerate(self.nodes) if not x.is_primitive]

    # ------------------------------------------------------------------ per-step evaluation
    tabulate_fields = tabulate_fields  # (hrl_torch.hierarchy.field_tables)

    def tabulate(self, observations: TensorDict, key: str = "observation") -> None:
        """Compute the context of every state once; ``context`` then only looks it up.

        For finite domains whose predicates (abstractions, termination, initiation, child
        masks, features) are functions of one integer field ``key`` alone: ``observations``
        holds every state, ``observations[key] == arange(S)``. Nodes with invocation memory
        or shaping rewards read more than the state and cannot be tabulated.
        """
        if self.memory_nodes:
            raise GraphError("nodes with invocation memory cannot be tabulated")
        n = observations.batch_size[0]
        if not torch.equal(observations[key].cpu(), torch.arange(n)):
            raise GraphError(f"tabulate needs every state once, in order: {key} == arange(S)")
        self._table_key = None
        ctx = self.context(observations)
        tables = {
            "tab_abstract": ctx.abstract,
            "tab_terminated": ctx.terminated,
            "tab_blocked": ctx.blocked,
            "tab_available": ctx.available,
        }
        if ctx.features is not None:
            tables["tab_features"] = ctx.features
        for name, value in tables.items():
            self.register_buffer(name, value, persistent=False)
        self._table_key = key
        self.table_observations = observations  # every state's observation, in order
        # every subtask has an available child in every state: no push can get stuck
        composite = ~self.node_is_primitive
        self.never_stuck = bool(ctx.available.any(-1)[:, composite].all())

    @property
    def table_key(self) -> str | None:
        """The observation field ``tabulate`` indexed its tables by (``None``: not tabulated)."""
        return self._table_key

    def context(
        self,
        obs: TensorDict,
        learner: torch.Tensor | None = None,
        memory: torch.Tensor | None = None,
    ) -> StepContext:
        """Abstract states, termination and available children of every node for ``obs``.

        ``learner [B]`` says which learner each row belongs to (default: all learner 0);
        ``memory [B, n_nodes, max_memory]`` is what each node's running invocation remembered
        (the executor's ``memory``; needed only by nodes with ``memory_size``).
        """
        b, device = batch_and_device(obs)
        if learner is None:
            learner = torch.zeros(b, dtype=torch.long, device=device)
        if self._table_key is not None:  # a tabulated graph: every field is a lookup
            return self._tabulated_context(obs, learner)
        if memory is None and self.memory_nodes:
            memory = torch.zeros(b, self.n_nodes, self.max_memory, device=device)
        abstract, terminated, initiable, mask = _predicates(self, obs, memory, b, device)
        blocked = terminated & ~self.node_event
        available = self._available(obs, initiable & ~blocked)
        if mask is not None:  # the tabulated nodes' child masks
            tables = self.field_tables
            narrowed = available.index_select(1, tables.nodes) & mask
            available.index_copy_(1, tables.nodes, narrowed)
        features = None
        if self.feature_nodes:
            features = torch.zeros(b, self.n_nodes, self.max_features, device=device)
            for k in self.feature_nodes:
                node = self.nodes[k]
                features[:, k, : node.n_features] = self._call(node.features, obs, memory, k)
        return StepContext(obs, learner, abstract, terminated, blocked, available, features)

    def _tabulated_context(self, obs: TensorDict, learner: torch.Tensor) -> StepContext:
        """``context`` of a tabulated graph: every field looked up by the state."""
        s = obs[self._table_key]
        try:
            features = lookup(self.tab_features, s) if self.max_features else None
            fields = (lookup(self.tab_abstract, s), lookup(self.tab_terminated, s),
                      lookup(self.tab_blocked, s), lookup(self.tab_available, s))  # fmt: skip
        except IndexError as err:  # (raised at once on the CPU): which value, which row
            n = self.tab_abstract.shape[0]
            bad = ((s < 0) | (s >= n)).nonzero()
            if not len(bad):
                raise
            row = int(bad[0, 0])
            raise GraphError(
                f"observation {self._table_key!r} is {int(s[row])} in env row {row}, outside "
                f"[0, {n}), the states the graph was tabulated over"
            ) from err
        return StepContext(
            obs,
            learner,
            *fields,
            features,
            table_row=s,
        )

    def _check_abstract_ranges(self, abstract: torch.Tensor, obs: TensorDict) -> None:
        """Every abstract state inside its node's ``[0, n_states)``, else a ``GraphError``.

        (A field out of its size reads -1 from the field tables: the error names the field.)
        """
        bad = (abstract < 0) | (abstract >= self.node_n_states)
        deferred = self.__dict__.get("deferred_ranges")  # (hrl_torch.training.deferred: no read)
        if deferred is not None and deferred.takes(bad):
            deferred.record(bad.any(1), cols=bad, abstract=abstract)
            return
        if bool(bad.any()):
            row, col = (int(v) for v in bad.nonzero()[0])
            outside = (
                None if self.field_tables is None else self.field_tables.field_outside(obs, row)
            )
            if outside is not None:
                raise GraphError(outside + " (the field tables' sizes, tabulate_fields)")
            raise GraphError(
                f"{self.names[col]!r}.abstract returned {int(abstract[row, col])}, outside "
                f"[0, {self.nodes[col].n_states}) (env row {row})"
            )

    def _available(self, obs: TensorDict, child_ok: torch.Tensor) -> torch.Tensor:
        """``[B, n_nodes, max_children]``: the children each node may start.

        ``child_ok [B, N]``: nodes that can start (one that would end at once cannot); each
        node's ``child_mask`` narrows its children further.
        """
        available = columns(child_ok, self.node_children_0) & self.child_valid
        for k in self._mask_nodes:
            mask = self.nodes[k].child_mask(obs)
            if mask is not None:
                available[:, k, : mask.shape[1]] &= mask.bool()
        return available

    @staticmethod
    def _node_columns(nodes, dtype, default, b, device, value_of) -> torch.Tensor:
        """``[B, n_nodes]`` filled with ``default`` except the columns of ``nodes``."""
        out = torch.full((b, len(nodes[1])), default, dtype=dtype, device=device)
        if nodes[0]:
            values = torch.stack([value_of(k).to(dtype) for k in nodes[0]], dim=1)
            out.index_copy_(1, nodes[2].to(device), values)
        return out

    def _abstract_of(self, obs: TensorDict, k: int) -> torch.Tensor:
        """Node ``k``'s abstract states; floats are an error, not silently truncated."""
        value = self.nodes[k].abstract(obs)
        if self.check_ranges and value.is_floating_point():
            raise GraphError(
                f"{self.names[k]!r}.abstract returned {value.dtype} values; abstract states are "
                "integer indices (return a long tensor)"
            )
        return value

    def _call(self, method, obs: TensorDict, memory: torch.Tensor | None, k: int):
        """``method(obs)``, or ``method(obs, memory of node k)`` for a memory node."""
        size = self.nodes[k].memory_size
        return method(obs, memory[:, k, :size]) if size else method(obs)

    def remember_all(self, obs: TensorDict) -> torch.Tensor | None:
        """What a new invocation of every memory node would record: ``[B, n_nodes, M]``."""
        if not self.memory_nodes:
            return None
        b, device = batch_and_device(obs)
        out = torch.zeros(b, self.n_nodes, self.max_memory, device=device)
        for k in self.memory_nodes:
            out[:, k, : self.nodes[k].memory_size] = self.nodes[k].remember(obs)
        return out

    def start_features(self, obs: TensorDict, features: torch.Tensor) -> torch.Tensor:
        """``features [B, N, F]`` with every memory node's as a new invocation would see them.

        A node with invocation memory reads its features relative to what it remembered when
        it started; an invocation starting at ``obs`` remembers ``remember(obs)``.
        """
        if not self.memory_feature_nodes:
            return features
        memory = self.remember_all(obs)
        out = features.clone()
        for k in self.memory_feature_nodes:
            node = self.nodes[k]
            out[:, k, : node.n_features] = node.features(obs, memory[:, k, : node.memory_size])
        return out

    def internal_rewards_at_termination(
        self, obs: TensorDict, memory: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Pseudo rewards of every node for terminating in ``obs``: ``[B, n_nodes]``.

        Memory nodes receive their invocation's ``memory`` (``[B, n_nodes, M]``) too.
        """
        b, device = batch_and_device(obs)
        out = torch.zeros(b, self.n_nodes, device=device)
        for k in self.internal_nodes:
            value = self._call(self.nodes[k].pseudo_reward, obs, memory, k)
            if value is not None:
                out[:, k] = value
        return out

    def shaping_rewards(
        self,
        obs: TensorDict,
        action: torch.Tensor,
        next_obs: TensorDict,
        memory: torch.Tensor | None = None,
    ) -> torch.Tensor | None:
        """Per-step internal rewards ``[B, n_nodes]`` (``None`` when no node defines them).

        Memory nodes receive their invocation's ``memory`` (``[B, n_nodes, M]``) too.
        """
        if not self.shaping_nodes:
            return None
        b, device = batch_and_device(obs)
        out = torch.zeros(b, self.n_nodes, device=device)
        for k in self.shaping_nodes:
            node = self.nodes[k]
            size = node.memory_size
            value = (
                node.shaping_reward(obs, action, next_obs, memory[:, k, :size])
                if size
                else node.shaping_reward(obs, action, next_obs)
            )
            if value is not None:
                out[:, k] = value
        return out


def _predicates(self: TaskGraph, obs: TensorDict, memory, b: int, device):
    """``[B, N]`` abstract, terminated, initiable, and the field tables' masks (or None).

    The nodes' calls, with the field tables' columns (``tabulate_fields``) looked up.
    """

    def called(nodes, dtype, default, method, *extra):
        value_of = _on_device(self, device, method, obs, *extra)
        return self._node_columns(nodes, dtype, default, b, device, value_of)

    tables, looked_up = self.field_tables, (None,) * 4
    abstract = called(self._abstract_nodes, torch.long, 0, "abstract")
    if tables is not None:  # one batch of ops for every tabulated node
        looked_up = tables.lookup(obs)
        abstract.index_copy_(1, tables.nodes, looked_up[0])
    if self.check_ranges:
        self._check_abstract_ranges(abstract, obs)
    terminated = called(self._terminating_nodes, torch.bool, False, "terminated", memory)
    initiable = called(self._initiable_nodes, torch.bool, True, "initiable")
    if tables is not None:
        terminated.index_copy_(1, tables.nodes, looked_up[1])
        initiable.index_copy_(1, tables.nodes, looked_up[2])
    return abstract, terminated, initiable, looked_up[3]


def _on_device(graph: TaskGraph, device, method: str, obs: TensorDict, memory=None):
    """``k -> node k's method(obs)``, which must be a tensor on the run's ``device``.

    (A tensor a subtask makes on the CPU would otherwise fail later, deep inside the step, or
    copy to the GPU at every step; the check reads no data.)
    """
    b = batch_and_device(obs)[0]

    def value_of(k: int) -> torch.Tensor:
        if method == "abstract":
            value = graph._abstract_of(obs, k)
        elif method == "initiable":
            value = graph.nodes[k].initiable(obs)
        else:
            value = graph._call(graph.nodes[k].terminated, obs, memory, k)
        if not torch.is_tensor(value) or not same_device(value.device, device):
            got = f"a tensor on {value.device}" if torch.is_tensor(value) else type(value).__name__
            raise GraphError(
                f"{graph.names[k]!r}.{method} ({_source_of(graph.nodes[k], method)}) "
                f"returned {got}, the run is on {device}: return a tensor made from the "
                f"observation's (torch.ones_like(...), device=obs[key].device; module-level "
                f"tables via devices.constant_on)"
            )
        if value.shape != (b,):
            raise GraphError(
                f"{graph.names[k]!r}.{method} ({_source_of(graph.nodes[k], method)}) returned "
                f"shape {list(value.shape)}, expected [{b}]: one value per env row (a [B, 1] "
                "result: .squeeze(-1))"
            )
        return value

    return value_of


def _source_of(node, method: str) -> str:
    """``file:line`` of the code behind ``node``'s ``method``.

    That is a callable given to the node (``Subtask(abstract=...)``), else the method itself.
    """
    given = vars(node).get("_fns", {}).get(method) or vars(node).get(f"_{method}")
    return defined_at(given if given is not None else getattr(node, method))
