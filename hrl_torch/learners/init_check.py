"""The discount trap: negative initial values under ``gamma^tau`` favour long children.

A discounted learner's completion target after child ``a`` ran for ``tau`` is
``gamma^tau * V(i, s')`` (Dietterich's Table 4, Equation 3.5 in continuous time). While
``V(i, s')`` is still near a negative start ``v0``, that target is ``gamma^tau * v0``: the
longer the child ran, the *higher* (less negative) it is, so the children that take longest
(waiting, driving to where nothing is) look best until learning undoes it. On four-agv the
root started at the subtasks' step cost (-49.96): a 20 s wait scaled it by 0.54, a 30 ms job
by 0.999, and the greedy root chose jobs whose item was absent (docs/defaults.md, "The
discount trap").

``discount_traps(learner)`` names the nodes where that can happen: the learner discounts
(``gamma < 1``), the node's children run for varying times (it has a non-primitive child, whose
duration is however long the child takes; or, in continuous time, any child), and some of its
initial values are below zero. The internal completions ``C~`` of a node with step costs of its
own (shaping rewards) are left out: there a negative start is the node's own reward, the
pessimism ``docs/defaults.md`` recommends for step-cost subtasks. ``warn_discount_trap`` turns
them into one warning; the trainer calls it at its start and ``hrl-torch check`` prints it.
"""

from __future__ import annotations

import warnings

from hrl_torch.hierarchy.graph import TaskGraph

__all__ = ["DiscountTrapWarning", "discount_traps", "warn_discount_trap"]


class DiscountTrapWarning(UserWarning):
    """A discounted learner starts a node below zero where its children's durations vary."""


def _varies(graph: TaskGraph, node: int, continuous: bool) -> bool:
    """Whether the children of ``node`` can take different times."""
    kids = graph.nodes[node].children_names
    return continuous or any(not graph.node(name).is_primitive for name in kids)


def discount_traps(learner, continuous: bool | None = None) -> list[tuple[str, float]]:
    """``(node, lowest initial value)`` for every node caught in the discount trap.

    Reads the learner's current tables (``learner.heads``: call it before training, at the
    start). ``continuous``: the task's primitives take varying times (default: the learner's
    own ``continuous`` flag, else False); in discrete time only nodes with a non-primitive
    child vary. Learners without tables or with ``gamma == 1`` have none.
    """
    gamma = float(getattr(learner, "gamma", 1.0))
    heads = getattr(learner, "heads", None)
    if gamma >= 1.0 or heads is None:
        return []
    graph, layout = learner.graph, getattr(learner, "layout", None)
    if layout is None or layout.table_node.device.type == "meta":  # (no values to read)
        return []
    table_node = layout.table_node.tolist()  # (one read at the start, not in a step)
    if continuous is None:
        continuous = bool(getattr(learner, "continuous", False))
    found = []
    for name, head in heads.items():
        table = getattr(head, "table", None)
        if table is None:
            continue
        node = table_node[table]
        if graph.nodes[node].is_primitive or not _varies(graph, node, continuous):
            continue
        own_costs = node in graph.shaping_nodes  # (its C~ holds its own step costs)
        tables = [
            t
            for kind, t in head.views().items()
            if t.numel() and not (own_costs and kind == "C_int")
        ]
        low = min((float(t.min()) for t in tables), default=0.0)  # (read once, at the start)
        if low < 0.0:
            found.append((name, low))
    return found


def warn_discount_trap(learner, continuous: bool | None = None, stacklevel: int = 2) -> list[str]:
    """Warn (``DiscountTrapWarning``) naming the nodes of ``discount_traps``; returns the text."""
    traps = discount_traps(learner, continuous)
    if not traps:
        return []
    names = ", ".join(f"{name} ({low:.4g})" for name, low in traps[:8])
    more = f" and {len(traps) - 8} more" if len(traps) > 8 else ""
    text = (
        f"{type(learner).__name__} (gamma {learner.gamma:g}) starts values below zero at "
        f"{names}{more}, whose children run for varying times: gamma^tau times a negative "
        "value favours the longest child until it is learned (docs/defaults.md, 'The discount "
        "trap'); start a node without step costs of its own at 0"
    )
    warnings.warn(text, DiscountTrapWarning, stacklevel=stacklevel)
    return [text]
