"""Compiling a task graph: validation, the node tables, and the instance tree with its paths.

``TaskGraph.__init__`` calls these once: ``validate`` (names, children, cycles, actions),
``compile_nodes`` (``node_*`` buffers), ``compile_instances`` (the DAG unrolled into instances,
one per path from the root: ``inst_*`` buffers) and ``compile_paths`` (each instance's path and
the descent codes the executor follows). ``graph`` is the ``TaskGraph`` being built: these
set its public buffers (``register_buffer``) and sizes.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from hrl_torch.hierarchy.subtask import GraphError, Node


def validate(root: str, nodes: Sequence[Node], n_actions: int | None) -> None:
    """A ``GraphError`` unless the nodes form a valid task DAG under ``root``."""
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


def compile_nodes(graph) -> None:
    """``node_*`` buffers: children, sizes, actions and heights of every node."""
    n = len(graph.nodes)
    width = max(len(node.children_names) for node in graph.nodes)
    children = torch.full((n, width), -1, dtype=torch.long)
    for k, node in enumerate(graph.nodes):
        for a, c in enumerate(node.children_names):
            children[k, a] = graph.index[c]
    height = [0] * n

    def node_height(k: int) -> int:
        node = graph.nodes[k]
        if node.is_primitive:
            return 0
        if height[k] == 0:
            height[k] = 1 + max(node_height(graph.index[c]) for c in node.children_names)
        return height[k]

    for k in range(n):
        node_height(k)
    graph.n_nodes = n
    graph.max_children = width

    def per_node(fn, dtype=torch.long) -> torch.Tensor:
        return torch.tensor([fn(x) for x in graph.nodes], dtype=dtype)

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
        graph.register_buffer(name, value, persistent=False)
    graph.register_buffer(
        "child_valid",
        torch.arange(width)[None, :] < graph.node_n_children[:, None],
        persistent=False,
    )
    graph.register_buffer("node_children_0", children.clamp_min(0), persistent=False)


def compile_instances(graph, max_instances: int) -> None:
    """``inst_*`` buffers: the DAG unrolled into instances (paths from the root)."""
    inst_node, inst_parent, inst_slot, inst_depth = (
        [graph.index[graph.root_name]],
        [-1],
        [-1],
        [0],
    )
    head = 0
    while head < len(inst_node):  # breadth first
        node = graph.nodes[inst_node[head]]
        for a, c in enumerate(node.children_names):
            inst_node.append(graph.index[c])
            inst_parent.append(head)
            inst_slot.append(a)
            inst_depth.append(inst_depth[head] + 1)
            if len(inst_node) > max_instances:
                raise GraphError(f"unrolled task tree exceeds {max_instances} instances")
        head += 1
    m = len(inst_node)
    inst_children = torch.full((m, graph.max_children), -1, dtype=torch.long)
    for k in range(1, m):
        inst_children[inst_parent[k], inst_slot[k]] = k
    graph.n_instances = m
    graph.max_levels = max(inst_depth) + 1  # stack slots, primitive included
    as_long = dict(dtype=torch.long)
    graph.register_buffer("inst_node", torch.tensor(inst_node, **as_long), persistent=False)
    graph.register_buffer("inst_parent", torch.tensor(inst_parent, **as_long), persistent=False)
    graph.register_buffer("inst_depth", torch.tensor(inst_depth, **as_long), persistent=False)
    graph.register_buffer("inst_children", inst_children, persistent=False)
    # row ``i * max_children + a``: the instance of child slot ``a`` of instance ``i``
    graph.register_buffer("inst_children_flat", inst_children.view(-1), persistent=False)
    # the executor's tables over ``instance + 1`` (0: an empty level): node, whether it is
    # non-primitive (it chooses), its env action, and its children (+ 1; 0: no child)
    node_1 = torch.tensor(inst_node[:1] + inst_node, **as_long)  # (0: the root's)
    composite_1 = torch.cat(
        [torch.zeros(1, dtype=torch.bool), ~graph.node_is_primitive[torch.tensor(inst_node)]]
    )
    children_1 = torch.cat(
        [torch.zeros(graph.max_children, dtype=torch.long), (inst_children + 1).view(-1)]
    )
    action_1 = torch.cat(
        [
            torch.zeros(1, dtype=torch.long),
            graph.node_action[torch.tensor(inst_node)].clamp_min(0),
        ]
    )
    for name, value in (
        ("inst_node_1", node_1),
        ("inst_composite_1", composite_1),
        ("inst_children_1", children_1),
        ("inst_action_1", action_1),
    ):
        graph.register_buffer(name, value, persistent=False)
    graph.register_buffer("inst_slot", torch.tensor(inst_slot, **as_long), persistent=False)
    graph.register_buffer(
        "inst_is_primitive", graph.node_is_primitive[graph.inst_node], persistent=False
    )
    compile_paths(graph, inst_parent, inst_slot, inst_depth)


def compile_paths(graph, inst_parent, inst_slot, inst_depth) -> None:
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
    m, d = graph.n_instances, graph.max_levels
    choosers = (~graph.inst_is_primitive).nonzero().squeeze(1)
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
    root_node = graph.inst_node[0]
    node = torch.where(inst >= 0, graph.inst_node[inst.clamp_min(0)], root_node)
    chooser = torch.where(inst >= 0, rank[inst.clamp_min(0)], len(choosers))
    graph.n_choosers = len(choosers)
    depth_1 = torch.tensor([-1] + list(inst_depth), dtype=torch.long)
    # descent codes: a chooser's rank, or Ic + (instance + 1) for a primitive (or 0: none)
    ic = len(choosers)
    kids = graph.inst_children[choosers]  # [Ic, A]
    kid_chooses = (kids >= 0) & ~graph.inst_is_primitive[kids.clamp_min(0)]
    next_code = torch.where(kid_chooses, rank[kids.clamp_min(0)], ic + kids + 1)
    # where a descent starts, by the instance on top; last (read at -1): an empty stack,
    # which starts at the root (chooser 0)
    start_code = torch.cat(
        [
            torch.where(graph.inst_is_primitive, ic + torch.arange(1, m + 1), rank),
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
        ("chooser_node", graph.inst_node[choosers]),
        ("chooser_depth", torch.tensor(inst_depth, dtype=torch.long)[choosers]),
        ("chooser_rank", rank),
    ):
        graph.register_buffer(name, value, persistent=False)
