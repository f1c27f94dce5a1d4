"""Task graphs: subtasks, primitive actions, validation and the compiled instance tree.

A non-primitive subtask is ``M_i = (S_i, I_i, T_i, A_i, R_i)`` (Definition 3.1): an abstract state
space (``abstract`` maps an observation to ``[0, n_states)``), an initiation set (``initiable``),
terminal states (``terminated``), children (``children`` plus an optional per-state ``child_mask``
for ``A_i(s)``) and internal rewards (``pseudo_reward`` on termination, ``shaping_reward`` per
step) that are used inside the subtask only.

Subtasks form a DAG; one subtask may be shared by several parents. ``TaskGraph`` validates the
DAG and unrolls it into a tree of *instances*, one per path from the root: the executor runs
instances, hierarchically optimal learners index their tables by instance (the Task-Stack is
part of their state, Section 3.4) and recursively optimal learners by subtask.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import torch
from tensordict import TensorDict
from torch import nn

from hrl_torch.ops import columns, lookup

ObsFn = Callable[[TensorDict], torch.Tensor]


class GraphError(ValueError):
    """An invalid task graph, or a subtask that misbehaves at run time."""


def _batch(obs: TensorDict) -> tuple[int, torch.device]:
    return obs.batch_size[0], obs.device if obs.device is not None else torch.device("cpu")


class Subtask(nn.Module):
    """A non-primitive subtask. Subclass it, or pass the predicates as callables.

    Args:
        name: unique name in the graph.
        children: names of child subtasks or primitives (the action set ``A_i``).
        n_states: size of the abstract state space ``S_i``.
        abstract: ``obs -> [B] long`` in ``[0, n_states)``; required when ``n_states > 1``.
        terminated: ``obs -> [B] bool``, the terminal set ``T_i`` (default: never, as a
            continuing root).
        initiable: ``obs -> [B] bool``, the initiation set ``I_i`` (default: everywhere).
        child_mask: ``obs -> [B, n_children] bool``, the state-dependent action set ``A_i(s)``.
        pseudo_reward: ``obs -> [B]``, internal reward on entering a terminal state (MAXQ).
        shaping_reward: ``(obs, action, next_obs) -> [B]``, internal reward per primitive step.
        event_termination: the predicate marks an *event* of the last step (e.g. "a part was
            delivered") rather than a terminal *state*: it ends a running invocation but does
            not make the subtask unavailable, or worth zero, where it holds.
        features: ``obs -> [B, n_features]`` float, a continuous state description for
            function approximation (policy-gradient nodes), beside the discrete ``abstract``.
        n_features: width of ``features``.
        remember: ``obs -> [B, memory_size]``, what an invocation records when it starts (e.g.
            the position it started from, to steer in a local frame). With
            ``memory_size > 0``, ``terminated``, ``features`` and ``pseudo_reward`` receive
            ``(obs, memory)`` and ``shaping_reward`` ``(obs, action, next_obs, memory)``.
            Such a subtask's termination depends on where it started, so it never blocks a
            start (as with ``event_termination``).
        memory_size: width of ``remember``.
    """

    is_primitive = False
    event_termination = False
    memory_size = 0

    def __init__(
        self,
        name: str,
        children: Sequence[str],
        n_states: int = 1,
        *,
        abstract: ObsFn | None = None,
        terminated: ObsFn | None = None,
        initiable: ObsFn | None = None,
        child_mask: ObsFn | None = None,
        pseudo_reward: ObsFn | None = None,
        shaping_reward: Callable[[TensorDict, torch.Tensor, TensorDict], torch.Tensor]
        | None = None,
        event_termination: bool | None = None,
        features: ObsFn | None = None,
        n_features: int = 0,
        remember: ObsFn | None = None,
        memory_size: int = 0,
    ) -> None:
        super().__init__()
        self.name = name
        self.n_features = int(n_features)
        if memory_size:
            self.memory_size = int(memory_size)
        if event_termination is not None:
            self.event_termination = bool(event_termination)
        self.children_names = tuple(children)
        self.n_states = int(n_states)
        self._fns = {
            "abstract": abstract,
            "terminated": terminated,
            "initiable": initiable,
            "child_mask": child_mask,
            "pseudo_reward": pseudo_reward,
            "shaping_reward": shaping_reward,
            "features": features,
            "remember": remember,
        }

    def _with_memory(self, fn, obs: TensorDict, memory: torch.Tensor | None):
        return fn(obs, memory) if self.memory_size else fn(obs)

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        """Abstract state index in ``[0, n_states)``, shape ``[B]``."""
        if self._fns["abstract"] is not None:
            return self._fns["abstract"](obs)
        if self.n_states != 1:
            raise GraphError(
                f"subtask {self.name!r} has n_states={self.n_states} but no abstract()"
            )
        b, device = _batch(obs)
        return torch.zeros(b, dtype=torch.long, device=device)

    def remember(self, obs: TensorDict) -> torch.Tensor | None:
        """What a new invocation records, ``[B, memory_size]`` (``None`` without memory)."""
        fn = self._fns["remember"]
        if fn is None:
            if self.memory_size:
                raise GraphError(f"subtask {self.name!r} has memory_size but no remember()")
            return None
        return fn(obs)

    def features(self, obs: TensorDict, memory: torch.Tensor | None = None) -> torch.Tensor | None:
        """Continuous state features ``[B, n_features]`` (``None`` when ``n_features == 0``)."""
        fn = self._fns["features"]
        if fn is None:
            if self.n_features:
                raise GraphError(f"subtask {self.name!r} has n_features but no features()")
            return None
        return self._with_memory(fn, obs, memory)

    def terminated(self, obs: TensorDict, memory: torch.Tensor | None = None) -> torch.Tensor:
        """Whether ``obs`` is in the terminal set ``T_i``, shape ``[B]``."""
        if self._fns["terminated"] is not None:
            return self._with_memory(self._fns["terminated"], obs, memory)
        b, device = _batch(obs)
        return torch.zeros(b, dtype=torch.bool, device=device)

    def initiable(self, obs: TensorDict) -> torch.Tensor:
        """Whether ``obs`` is in the initiation set ``I_i``, shape ``[B]``."""
        if self._fns["initiable"] is not None:
            return self._fns["initiable"](obs)
        b, device = _batch(obs)
        return torch.ones(b, dtype=torch.bool, device=device)

    def child_mask(self, obs: TensorDict) -> torch.Tensor | None:
        """``A_i(s)`` as ``[B, n_children]`` bool, or ``None`` when every child is allowed."""
        fn = self._fns["child_mask"]
        return None if fn is None else fn(obs)

    def pseudo_reward(
        self, obs: TensorDict, memory: torch.Tensor | None = None
    ) -> torch.Tensor | None:
        """Internal reward for terminating in ``obs`` (``None`` means zero)."""
        fn = self._fns["pseudo_reward"]
        return None if fn is None else self._with_memory(fn, obs, memory)

    def shaping_reward(
        self,
        obs: TensorDict,
        action: torch.Tensor,
        next_obs: TensorDict,
        memory: torch.Tensor | None = None,
    ) -> torch.Tensor | None:
        """Internal reward for one primitive step inside this subtask (``None`` means zero)."""
        fn = self._fns["shaping_reward"]
        if fn is None:
            return None
        return fn(obs, action, next_obs, memory) if self.memory_size else fn(obs, action, next_obs)

    def has_shaping_rewards(self) -> bool:
        """Whether this subtask defines per-step shaping rewards."""
        overridden = type(self).shaping_reward is not Subtask.shaping_reward
        return overridden or self._fns["shaping_reward"] is not None

    def has_internal_rewards(self) -> bool:
        """Whether this subtask defines pseudo or shaping rewards (so internal != external)."""
        cls = type(self)
        overridden = (
            cls.pseudo_reward is not Subtask.pseudo_reward
            or cls.shaping_reward is not Subtask.shaping_reward
        )
        given = self._fns["pseudo_reward"] is not None or self._fns["shaping_reward"] is not None
        return overridden or given

    def extra_repr(self) -> str:
        """Shown by ``print(module)``."""
        return f"name={self.name!r}, children={list(self.children_names)}, n_states={self.n_states}"


class Primitive(nn.Module):
    """A primitive action: always executable, terminates after one step.

    Args:
        name: unique name in the graph.
        action: the env action index it executes (discrete action spaces).
        n_states: size of the abstract state space of its value table ``V(a, s)``; the default
            1 says its expected reward does not depend on the state (Dietterich's leaf
            irrelevance).
        abstract: ``obs -> [B] long``; required when ``n_states > 1``.
        action_dim: for a continuous action space, the width of the action vector; its value is
            chosen by the parent's policy when the primitive is pushed (``action`` unused).
    """

    is_primitive = True
    children_names: tuple[str, ...] = ()
    n_features = 0
    memory_size = 0
    event_termination = False

    def __init__(
        self,
        name: str,
        action: int = -1,
        n_states: int = 1,
        abstract: ObsFn | None = None,
        action_dim: int = 0,
    ):
        super().__init__()
        self.name = name
        self.action = int(action)
        self.action_dim = int(action_dim)
        self.n_states = int(n_states)
        self._abstract = abstract

    def abstract(self, obs: TensorDict) -> torch.Tensor:
        """Abstract state index of ``V(a, s)``, shape ``[B]``."""
        if self._abstract is not None:
            return self._abstract(obs)
        if self.n_states != 1:
            raise GraphError(
                f"primitive {self.name!r} has n_states={self.n_states} but no abstract"
            )
        b, device = _batch(obs)
        return torch.zeros(b, dtype=torch.long, device=device)

    def has_internal_rewards(self) -> bool:
        """Primitives carry no internal rewards."""
        return False

    def extra_repr(self) -> str:
        """Shown by ``print(module)``."""
        return f"name={self.name!r}, action={self.action}, n_states={self.n_states}"


Node = Subtask | Primitive


def _overrides(node: Node, method: str) -> bool:
    """Whether ``node`` defines ``method`` itself (subclass override or a callable given)."""
    base = Primitive if node.is_primitive else Subtask
    if getattr(type(node), method) is not getattr(base, method):
        return True
    if node.is_primitive:
        return method == "abstract" and node._abstract is not None
    return node._fns.get(method) is not None


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


class TaskGraph(nn.Module):
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
        self._validate(root, nodes, n_actions)
        self.nodes = nn.ModuleList(nodes)
        self.names = [n.name for n in nodes]
        self.index = {name: k for k, name in enumerate(self.names)}
        self.root_name = root
        self.n_actions = n_actions
        self._compile(max_instances)

    # ------------------------------------------------------------------ validation
    @staticmethod
    def _validate(root: str, nodes: Sequence[Node], n_actions: int | None) -> None:
        names = [n.name for n in nodes]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise GraphError(f"duplicate node names: {dup}")
        by_name = {n.name: n for n in nodes}
        if root not in by_name:
            raise GraphError(f"root {root!r} is not a node of the graph")
        if by_name[root].is_primitive:
            raise GraphError(f"root {root!r} must be a subtask, not a primitive")
        kinds = {bool(n.action_dim) for n in nodes if n.is_primitive}
        if len(kinds) > 1:
            raise GraphError("primitives must be all discrete or all continuous (action_dim > 0)")
        for node in nodes:
            if node.n_states < 1:
                raise GraphError(f"{node.name!r}: n_states must be >= 1, got {node.n_states}")
            if node.is_primitive:
                if node.action_dim:
                    continue
                if n_actions is not None and not 0 <= node.action < n_actions:
                    raise GraphError(
                        f"primitive {node.name!r} has action {node.action}, outside the env's "
                        f"action space [0, {n_actions})"
                    )
                continue
            if not node.children_names:
                raise GraphError(f"subtask {node.name!r} has no children")
            unknown = [c for c in node.children_names if c not in by_name]
            if unknown:
                raise GraphError(f"subtask {node.name!r} has unknown children {unknown}")
            if len(set(node.children_names)) != len(node.children_names):
                raise GraphError(f"subtask {node.name!r} lists a child twice")
        # cycle check: depth-first search with colours
        colour: dict[str, int] = {}

        def visit(name: str, path: list[str]) -> None:
            colour[name] = 1
            for child in by_name[name].children_names:
                if colour.get(child) == 1:
                    cycle = path[path.index(child) :] + [child] if child in path else [name, child]
                    raise GraphError(f"task graph has a cycle: {' -> '.join(cycle)}")
                if colour.get(child) is None:
                    visit(child, path + [child])
            colour[name] = 2

        for name in names:
            if colour.get(name) is None:
                visit(name, [name])

    # ------------------------------------------------------------------ compilation
    def _compile(self, max_instances: int) -> None:
        """Tensors of the node graph, of its unrolled instance tree, and per-node capabilities."""
        self._compile_nodes()
        self._compile_instances(max_instances)
        self._compile_capabilities()

    def _compile_nodes(self) -> None:
        """``node_*`` buffers: children, sizes, actions and heights of every node."""
        n = len(self.nodes)
        width = max(len(node.children_names) for node in self.nodes)
        children = torch.full((n, width), -1, dtype=torch.long)
        for k, node in enumerate(self.nodes):
            for a, c in enumerate(node.children_names):
                children[k, a] = self.index[c]
        height = [0] * n

        def node_height(k: int) -> int:
            node = self.nodes[k]
            if node.is_primitive:
                return 0
            if height[k] == 0:
                height[k] = 1 + max(node_height(self.index[c]) for c in node.children_names)
            return height[k]

        for k in range(n):
            node_height(k)
        self.n_nodes = n
        self.max_children = width

        def per_node(fn, dtype=torch.long) -> torch.Tensor:
            return torch.tensor([fn(x) for x in self.nodes], dtype=dtype)

        for name, value in (
            ("node_children", children),
            ("node_n_children", per_node(lambda x: len(x.children_names))),
            ("node_is_primitive", per_node(lambda x: x.is_primitive, torch.bool)),
            ("node_n_states", per_node(lambda x: x.n_states)),
            ("node_action", per_node(lambda x: x.action if x.is_primitive else -1)),
            ("node_height", torch.tensor(height, dtype=torch.long)),
            # nodes whose termination predicate never blocks a start: events and memory nodes
            ("node_event", per_node(lambda x: bool(x.event_termination or x.memory_size), None)),
        ):
            self.register_buffer(name, value, persistent=False)
        self.register_buffer(
            "child_valid",
            torch.arange(width)[None, :] < self.node_n_children[:, None],
            persistent=False,
        )
        self.register_buffer("node_children_0", children.clamp_min(0), persistent=False)

    def _compile_instances(self, max_instances: int) -> None:
        """``inst_*`` buffers: the DAG unrolled into instances (paths from the root)."""
        inst_node, inst_parent, inst_slot, inst_depth = (
            [self.index[self.root_name]],
            [-1],
            [-1],
            [0],
        )
        head = 0
        while head < len(inst_node):  # breadth first
            node = self.nodes[inst_node[head]]
            for a, c in enumerate(node.children_names):
                inst_node.append(self.index[c])
                inst_parent.append(head)
                inst_slot.append(a)
                inst_depth.append(inst_depth[head] + 1)
                if len(inst_node) > max_instances:
                    raise GraphError(f"unrolled task tree exceeds {max_instances} instances")
            head += 1
        m = len(inst_node)
        inst_children = torch.full((m, self.max_children), -1, dtype=torch.long)
        for k in range(1, m):
            inst_children[inst_parent[k], inst_slot[k]] = k
        self.n_instances = m
        self.max_levels = max(inst_depth) + 1  # stack slots, primitive included
        as_long = dict(dtype=torch.long)
        self.register_buffer("inst_node", torch.tensor(inst_node, **as_long), persistent=False)
        self.register_buffer("inst_parent", torch.tensor(inst_parent, **as_long), persistent=False)
        self.register_buffer("inst_depth", torch.tensor(inst_depth, **as_long), persistent=False)
        self.register_buffer("inst_children", inst_children, persistent=False)
        # row ``i * max_children + a``: the instance of child slot ``a`` of instance ``i``
        self.register_buffer("inst_children_flat", inst_children.view(-1), persistent=False)
        # the executor's tables over ``instance + 1`` (0: an empty level): node, whether it is
        # non-primitive (it chooses), its env action, and its children (+ 1; 0: no child)
        node_1 = torch.tensor(inst_node[:1] + inst_node, **as_long)  # (0: the root's)
        composite_1 = torch.cat(
            [torch.zeros(1, dtype=torch.bool), ~self.node_is_primitive[torch.tensor(inst_node)]]
        )
        children_1 = torch.cat(
            [torch.zeros(self.max_children, dtype=torch.long), (inst_children + 1).view(-1)]
        )
        action_1 = torch.cat(
            [
                torch.zeros(1, dtype=torch.long),
                self.node_action[torch.tensor(inst_node)].clamp_min(0),
            ]
        )
        for name, value in (
            ("inst_node_1", node_1),
            ("inst_composite_1", composite_1),
            ("inst_children_1", children_1),
            ("inst_action_1", action_1),
        ):
            self.register_buffer(name, value, persistent=False)
        self.register_buffer("inst_slot", torch.tensor(inst_slot, **as_long), persistent=False)
        self.register_buffer(
            "inst_is_primitive", self.node_is_primitive[self.inst_node], persistent=False
        )
        self._compile_paths(inst_parent, inst_slot, inst_depth)

    def _compile_paths(self, inst_parent, inst_slot, inst_depth) -> None:
        """``path_*`` buffers: the whole Task-Stack of each instance, and the choosers.

        An instance at depth ``d`` sits at stack level ``d`` and the stack below it is its
        path from the root, so the stack of a row is a function of the instance on top:
        ``path_inst_1[i + 1]`` is that stack ``[D]`` (-1 above the top; row 0: an empty stack),
        ``path_node_1`` its nodes (the root's node above the top), ``path_child_1`` the child
        slot each level chose (0 at and above the top), ``path_chooser_1`` each level's rank
        among the *choosers* (the non-primitive instances, ``choosers [Ic]``; ``Ic`` at and
        above the top). Instances are numbered breadth first, so along a path the ids grow:
        the instance on top of a stack is its largest id.
        """
        m, d = self.n_instances, self.max_levels
        choosers = (~self.inst_is_primitive).nonzero().squeeze(1)
        rank = torch.full((m,), len(choosers), dtype=torch.long)
        rank[choosers] = torch.arange(len(choosers))
        inst = torch.full((m + 1, d), -1, dtype=torch.long)
        child = torch.zeros(m + 1, d, dtype=torch.long)
        for k in range(m):
            level, slot, i = inst_depth[k], 0, k
            while i >= 0:
                inst[k + 1, level] = i
                child[k + 1, level] = slot
                level, slot, i = level - 1, inst_slot[i], inst_parent[i]
        root_node = self.inst_node[0]
        node = torch.where(inst >= 0, self.inst_node[inst.clamp_min(0)], root_node)
        chooser = torch.where(inst >= 0, rank[inst.clamp_min(0)], len(choosers))
        self.n_choosers = len(choosers)
        depth_1 = torch.tensor([-1] + list(inst_depth), dtype=torch.long)
        # descent codes: a chooser's rank, or Ic + (instance + 1) for a primitive (or 0: none)
        ic = len(choosers)
        kids = self.inst_children[choosers]  # [Ic, A]
        kid_chooses = (kids >= 0) & ~self.inst_is_primitive[kids.clamp_min(0)]
        next_code = torch.where(kid_chooses, rank[kids.clamp_min(0)], ic + kids + 1)
        # where a descent starts, by the instance on top; last (read at -1): an empty stack,
        # which starts at the root (chooser 0)
        start_code = torch.cat(
            [
                torch.where(self.inst_is_primitive, ic + torch.arange(1, m + 1), rank),
                torch.zeros(1, dtype=torch.long),
            ]
        )
        for name, value in (
            ("chooser_next_code", next_code.view(-1)),
            ("inst_start_code", start_code),
            ("path_inst_1", inst),
            ("path_node_1", node),
            ("path_child_1", child),
            ("path_chooser_1", chooser),
            ("inst_depth_1", depth_1),
            ("choosers", choosers),
            ("chooser_node", self.inst_node[choosers]),
            ("chooser_depth", torch.tensor(inst_depth, dtype=torch.long)[choosers]),
            ("chooser_rank", rank),
        ):
            self.register_buffer(name, value, persistent=False)

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
        self._abstract_nodes = self._custom(lambda x: x.n_states > 1 or _overrides(x, "abstract"))
        self._terminating_nodes = self._custom(
            lambda x: not x.is_primitive and _overrides(x, "terminated")
        )
        self._initiable_nodes = self._custom(
            lambda x: not x.is_primitive and _overrides(x, "initiable")
        )
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
        b, device = _batch(obs)
        if learner is None:
            learner = torch.zeros(b, dtype=torch.long, device=device)
        if self._table_key is not None:  # a tabulated graph: every field is a lookup
            return self._tabulated_context(obs, learner)
        if memory is None and self.memory_nodes:
            memory = torch.zeros(b, self.n_nodes, self.max_memory, device=device)
        abstract = self._node_columns(
            self._abstract_nodes, torch.long, 0, b, device, lambda k: self._abstract_of(obs, k)
        )
        if self.check_ranges:
            self._check_abstract_ranges(abstract)
        terminated = self._node_columns(
            self._terminating_nodes,
            torch.bool,
            False,
            b,
            device,
            lambda k: self._call(self.nodes[k].terminated, obs, memory, k),
        )
        initiable = self._node_columns(
            self._initiable_nodes,
            torch.bool,
            True,
            b,
            device,
            lambda k: self.nodes[k].initiable(obs),
        )
        blocked = terminated & ~self.node_event
        available = self._available(obs, initiable & ~blocked)
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
        features = lookup(self.tab_features, s) if self.max_features else None
        return StepContext(
            obs,
            learner,
            lookup(self.tab_abstract, s),
            lookup(self.tab_terminated, s),
            lookup(self.tab_blocked, s),
            lookup(self.tab_available, s),
            features,
            table_row=s,
        )

    def _check_abstract_ranges(self, abstract: torch.Tensor) -> None:
        """Every abstract state inside its node's ``[0, n_states)``, else a ``GraphError``."""
        bad = (abstract < 0) | (abstract >= self.node_n_states)
        if bool(bad.any()):
            row, col = (int(v) for v in bad.nonzero()[0])
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
        for k, x in enumerate(self.nodes):
            if x.is_primitive:
                continue
            mask = x.child_mask(obs)
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
        b, device = _batch(obs)
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
        b, device = _batch(obs)
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
        b, device = _batch(obs)
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
