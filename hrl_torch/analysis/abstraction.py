"""Dietterich's conditions for safe state abstraction, checked on a finite model.

MAXQ (Dietterich 2000, Section 5.1) stores ``V(a, s)`` of a primitive ``a`` by ``a``'s abstract
state and the completion ``C(i, s, j)`` of child ``j`` in subtask ``i`` by ``i``'s abstract state.
An abstraction is safe when those values agree on the states it merges, under every abstract
hierarchical policy. Five conditions license merging; this module checks them on every pair of
merged states a policy can meet (``check_abstractions``):

1. **Max-node irrelevance** (Condition 1): the merged states of ``i`` give the same distribution
   of ``i``'s next states and the same child values, whatever the policies below ``i``. Checked
   as *probabilistic bisimulation* of ``i``'s run: the coarsest partition of the full states in
   which equivalent states carry the same labels (``i``'s termination and, for ``i`` and every
   subtask below it, its abstract state, termination and usable children), give the same
   expected reward for every primitive below ``i`` and move with equal probability into every
   block under every such primitive. Abstract policies read only the labels, so bisimilar
   states have equal values and completions under all of them: sound, and stricter than
   Dietterich's factorisation only where differences cancel in expectation or hide behind a
   mask (every primitive below ``i`` is compared, usable or not).
2. **Leaf irrelevance** (Condition 2): a primitive merges only states with equal expected reward
   ``r[s, a]`` among the states where its parent can push it. Exact.
3. **Result distribution irrelevance** (Condition 3): child ``j`` of ``i`` ends in the same full
   states with the same probabilities from both merged states, whatever ``j``'s policy. For a
   primitive child (one step) this is checked exactly. For a subtask child it is checked
   soundly but not completely: accepted when ``j`` can end in one state only, the same from
   both (a certain result, like taxi's Get ending where the passenger waits). The states ``j``
   can end in under some hierarchical policy are found exactly, by reachability on the
   Task-Stack (usable children, pops of terminated subtasks). A random result that no policy
   can change is reported although it is safe. As in Dietterich, only for ``gamma == 1``: with
   discounting the durations would have to match too.
4. **Termination** (Condition 4): ``C(i, s, j) = 0`` when every state ``j`` can end in ends
   ``i`` (with equal pseudo-rewards there); applied exactly, for any ``gamma``.
5. **Shielding** (Condition 5): no values are needed where an ancestor (or ``i`` itself) has
   terminated; applied exactly by comparing only the decision states a hierarchical policy can
   reach from the starts (``hrl_torch.analysis.hierarchy``).

A merged pair is reported when none of 1, 3 and 4 holds for some child of ``i`` usable in both
states (under max-node irrelevance for a primitive child, under result distribution
irrelevance for a subtask child), and for a primitive when 2 fails. Termination and shielding
only permit merging, so no violation carries their name: a merge that needs them where they do
not hold is reported under 1 or 3. Whether a termination predicate is constant on each abstract
state does not matter here: the framework reads termination from the full state.

Scope: projected values (the child runs until it or its parent ends, as Dietterich's ``C``);
per-instance tables of hierarchically optimal learners also carry the reward after the parent
ends, which these conditions do not cover. Pseudo-rewards count where the parent ends; shaping
rewards are ignored; subtasks with invocation memory are not supported. Vectorised over states;
a pair check builds ``[n, n]`` tables per subtask and child, fine for a few thousand states.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hrl_torch.analysis.chains import F64, FiniteModel
from hrl_torch.analysis.hierarchy import Unrolled
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError

MAX_NODE_IRRELEVANCE = "max-node irrelevance"
LEAF_IRRELEVANCE = "leaf irrelevance"
RESULT_DISTRIBUTION_IRRELEVANCE = "result distribution irrelevance"
_TOL = 1e-9


@dataclass(frozen=True)
class Violation:
    """Two full states an abstraction merges although their values can differ.

    Attributes:
        condition: the condition that fails (one of the module's three constants).
        subtask: the node whose abstraction merges the states.
        child: for a completion ``C(subtask, s, child)``, the child whose values differ.
        abstract_state: the abstract state of ``subtask`` both states map to.
        states: the two full states.
        message: one line saying how they differ.
    """

    condition: str
    subtask: str
    child: str | None
    abstract_state: int
    states: tuple[int, int]
    message: str


def check_abstractions(
    graph: TaskGraph,
    model: FiniteModel,
    starts: torch.Tensor | None = None,
    gamma: float = 1.0,
) -> list[Violation]:
    """Every unsafe merge of ``graph``'s abstractions on ``model`` (the module docstring).

    Args:
        graph: the task graph whose abstractions are checked.
        model: the finite model; its observations feed the graph's predicates.
        starts: start states of the root (bool or indices; default: all). Only states a
            hierarchical policy reaches from them are compared.
        gamma: discount of the values (result distribution irrelevance needs 1).

    Returns:
        One ``Violation`` per node, child and abstract state that merges unsafe states.
    """
    if graph.memory_nodes:
        raise GraphError("abstraction checks need predicates of the state alone (no memory)")
    u = Unrolled(graph, model, starts)
    pseudo = graph.internal_rewards_at_termination(model.observations).to(F64)  # [S, nodes]
    found = _leaf_irrelevance(u)
    for i in graph.subtasks():
        found += _completions(u, i, pseudo[:, i], gamma)
    return found


# --------------------------------------------------------------------------- Condition 2
def _leaf_irrelevance(u: Unrolled) -> list[Violation]:
    """Primitives whose abstract state mixes different expected rewards ``r[s, a]``."""
    g, found = u.graph, []
    pushed = torch.zeros(g.n_nodes, u.n, dtype=torch.bool)  # where a parent can push the node
    for i in g.subtasks():
        kids = _children(g, i)
        pushed[kids] |= u.node_reach[i] & u.ok_node[i, : len(kids)]
    for a in _primitives(g):
        states = pushed[a].nonzero().squeeze(1)
        x = u.abstract[a, states]
        r = u.model.reward[states, int(g.node_action[a])]
        width = int(g.node_n_states[a])
        lo = torch.full((width,), torch.inf, dtype=F64).scatter_reduce(0, x, r, "amin")
        hi = torch.full((width,), -torch.inf, dtype=F64).scatter_reduce(0, x, r, "amax")
        for xa in (hi - lo > _TOL).nonzero().squeeze(1).tolist():
            s1 = int(states[(x == xa) & (r == lo[xa])][0])
            s2 = int(states[(x == xa) & (r == hi[xa])][0])
            found.append(
                Violation(
                    LEAF_IRRELEVANCE,
                    g.names[a],
                    None,
                    xa,
                    (s1, s2),
                    f"{g.names[a]!r} merges states {s1} and {s2} (abstract state {xa}), whose "
                    f"expected rewards differ: {float(lo[xa]):g} and {float(hi[xa]):g}",
                )
            )
    return found


# --------------------------------------------------------------------------- Conditions 1, 3, 4
def _completions(u: Unrolled, i: int, pseudo: torch.Tensor, gamma: float) -> list[Violation]:
    """Merged decision states of ``i`` where some ``C(i, s, j)`` can differ."""
    g, found = u.graph, []
    x = u.abstract[i]
    blocks = None  # the bisimulation, computed on the first merge it is needed for
    for slot, j in enumerate(_children(g, i)):
        cand = (u.node_reach[i] & u.ok_node[i, slot]).nonzero().squeeze(1)
        xs = x[cand]
        merged = (xs[:, None] == xs[None, :]).triu(1)
        if not bool(merged.any()):
            continue
        blocks = _bisimulation(u, i, pseudo) if blocks is None else blocks
        km = blocks[cand]
        unsettled = merged & (km[:, None] != km[None, :])  # max-node irrelevance fails
        if not bool(unsettled.any()):
            continue
        key, outcome, end_values = _results(u, i, j, cand, pseudo, gamma)
        bad = unsettled & (key[:, None] != key[None, :])  # and Conditions 3 and 4 fail too
        reported = set()
        for a, b in bad.nonzero().tolist():
            if int(xs[a]) in reported:
                continue
            reported.add(int(xs[a]))
            found.append(
                _completion_violation(
                    u, i, j, cand[[a, b]], int(xs[a]), outcome[[a, b]], end_values, gamma
                )
            )
    return found


def _bisimulation(u: Unrolled, i: int, pseudo: torch.Tensor) -> torch.Tensor:
    """Block ``[S]`` of every full state in the coarsest bisimulation of ``i``'s run.

    Labels: whether ``i`` ended (and its pseudo-reward there); elsewhere the abstract state,
    termination and usable children of ``i`` and of every subtask below it, and the expected
    reward of every primitive below it. Blocks split until every state of a block moves into
    every block with the same probability under every primitive below ``i``.
    """
    g, m = u.graph, u.model
    below = _subtree(g, i)
    inner = [d for d in below if not bool(g.node_is_primitive[d])]
    actions = torch.unique(g.node_action[[d for d in below if bool(g.node_is_primitive[d])]])
    ended = u.term[i]
    label = torch.cat(
        [
            u.abstract[inner].T.to(F64),
            u.term[inner].T.to(F64),
            u.ok_node[inner].flatten(0, 1).T.to(F64),
            m.reward[:, actions],
        ],
        1,
    )
    label = torch.where(ended[:, None], 0.0, label)
    blocks = _ids(
        torch.cat([ended[:, None].to(F64), torch.where(ended, pseudo, 0.0)[:, None], label], 1)
    )
    p = m.transition[:, actions]
    s, a, t = (p > 0).nonzero(as_tuple=True)
    keep = ~ended[s]  # ended states are absorbing: i's run is over there
    s, a, t = s[keep], a[keep], t[keep]
    prob = p[s, a, t]
    while True:
        n_blocks = int(blocks.max()) + 1
        parts = [blocks]
        for k in range(len(actions)):  # one id per distribution over blocks, action by action
            sel = a == k
            dist = torch.zeros(u.n, n_blocks, dtype=F64)
            dist.index_put_((s[sel], blocks[t[sel]]), prob[sel], accumulate=True)
            parts.append(_ids(dist))
        finer = _ids(torch.stack(parts, 1).to(F64))
        if int(finer.max()) == n_blocks - 1:
            return finer
        blocks = finer


def _results(u: Unrolled, i: int, j: int, cand, pseudo, gamma: float):
    """Where child ``j`` of ``i`` ends from each state of ``cand``, as ``i`` values it.

    Outcomes are full states, except that the states where ``i`` ends count as one outcome per
    pseudo-reward there (the completion is that reward). Returns:

    - ``key [n]``: equal keys, equal result distributions under every policy (a unique
      negative key where that is not shown);
    - ``outcome [n, S + E]``: the distribution over outcomes (primitive ``j``: one step) or
      the outcomes ``j`` can end in under some policy (subtask ``j``; just one: its result is
      certain);
    - ``end_values [E]``: the pseudo-reward of each "``i`` ends" outcome.
    """
    g, m, n = u.graph, u.model, u.n
    ends_i = u.term[i]
    values, end_kind = torch.unique(pseudo[ends_i], return_inverse=True)
    column = torch.arange(n)
    column[ends_i] = n + end_kind
    width = n + len(values)
    no_key = -1 - torch.arange(len(cand))
    if bool(g.node_is_primitive[j]):  # one step: compare the distributions themselves
        dist = torch.zeros(len(cand), width, dtype=F64)
        dist.index_add_(1, column, m.transition[cand, int(g.node_action[j])])
        return _ids(dist), dist, values
    hit = _reachable_ends(u, i, j, cand, column, width).to(F64)
    single = hit.sum(1) == 1
    first = hit.argmax(1)
    if gamma < 1.0:  # durations matter: only "i always ends, pseudo-reward 0" is safe
        zero = (values == 0).nonzero().squeeze(1)
        single &= (first == n + zero[0]) if len(zero) else torch.zeros_like(single)
    return torch.where(single, first, no_key), hit, values


def _reachable_ends(u: Unrolled, i: int, j: int, cand, column, width: int) -> torch.Tensor:
    """Outcomes ``[n, width]`` child ``j`` of ``i`` can end in from ``cand``, under any policy.

    The run of one instance ``k`` of ``j`` on the Task-Stack: from a decision state ``(q, s)``
    (``q`` at or below ``k``) any chain of usable children pushes a primitive; after its step to
    ``t`` the run is over if ``i`` or ``j`` terminated, else the shallowest terminated instance
    pops with everything below it and its parent decides next.
    """
    g, n, m = u.graph, u.n, u.model
    k = next(
        q
        for q in range(1, g.n_instances)
        if int(g.inst_node[q]) == j and int(g.inst_node[g.inst_parent[q]]) == i
    )
    sub, head = [k], 0
    while head < len(sub):  # breadth first: parents before children
        sub += [c for c in g.inst_children[sub[head]].tolist() if c >= 0]
        head += 1
    inner = [q for q in sub if not bool(u.is_prim[q])]
    prims = [q for q in sub if bool(u.is_prim[q])]
    local = torch.full((g.n_instances,), -1)
    local[inner] = torch.arange(len(inner))
    push = {}  # push[q] [n_prims, S]: each primitive can be pushed from q in s
    for q in reversed(inner):
        rows = torch.zeros(len(prims), n, dtype=torch.bool)
        for w, c in enumerate(g.inst_children[q].tolist()):
            if c >= 0:
                below = push[c] if c in push else (torch.tensor(prims) == c)[:, None]
                rows |= below & u.ok[q, w]
        push[q] = rows
    over = u.term[i] | u.term[j]
    src, dst, exit_src, exit_col = [], [], [], []
    for jp, p in enumerate(prims):
        top, q = torch.full((n,), int(g.inst_parent[p])), int(g.inst_parent[p])
        while q != k:  # the shallowest terminated instance below k pops: its parent is next
            top = torch.where(u.term[int(g.inst_node[q])], int(g.inst_parent[q]), top)
            q = int(g.inst_parent[q])
        s_all, t_all = (m.transition[:, int(g.node_action[int(g.inst_node[p])])] > 0).nonzero(
            as_tuple=True
        )
        for q in inner:
            sel = push[q][jp, s_all]
            s, t = s_all[sel], t_all[sel]
            done = over[t]
            exit_src.append(local[q] * n + s[done])
            exit_col.append(column[t[done]])
            src.append(local[q] * n + s[~done])
            dst.append(local[top[t[~done]]] * n + t[~done])
    src, dst, exit_src, exit_col = (torch.cat(x) for x in (src, dst, exit_src, exit_col))
    reach = torch.zeros(len(cand), len(inner) * n, dtype=torch.bool)
    reach[torch.arange(len(cand)), local[k] * n + cand] = True
    while True:
        step = torch.zeros(reach.shape, dtype=F64).index_add_(1, dst, reach[:, src].to(F64))
        wider = reach | (step > 0)
        if torch.equal(wider, reach):
            break
        reach = wider
    hit = torch.zeros(len(cand), width, dtype=F64)
    return hit.index_add_(1, exit_col, reach[:, exit_src].to(F64)) > 0


def _completion_violation(u, i, j, pair, x: int, outcome, end_values, gamma) -> Violation:
    """The violation for the merged states ``pair`` with their ``outcome`` rows."""
    g = u.graph
    s1, s2 = pair.tolist()
    where1, where2 = (_outcomes(g.names[i], u.n, row, end_values) for row in outcome)
    head = f"{g.names[i]!r} merges states {s1} and {s2} (abstract state {x}), but "
    if bool(g.node_is_primitive[j]):
        condition = MAX_NODE_IRRELEVANCE
        tail = (
            f"{g.names[j]!r} leads to {where1} from {s1} and to {where2} from {s2}, "
            f"which {g.names[i]!r}'s run tells apart"
        )
    else:
        condition = RESULT_DISTRIBUTION_IRRELEVANCE
        if where1 != where2:
            tail = f"{g.names[j]!r} can end in {where1} from {s1} and in {where2} from {s2}"
        elif gamma < 1.0:
            tail = f"{g.names[j]!r} ends in {where1} from both, but gamma < 1 sees its durations"
        else:
            tail = f"where {g.names[j]!r} ends ({where1}) depends on its policy"
    return Violation(condition, g.names[i], g.names[j], x, (s1, s2), head + tail)


def _outcomes(name: str, n: int, row: torch.Tensor, end_values, most: int = 4) -> str:
    """``{3, 7 (p=0.5), Go ends}``: the outcomes of one row of ``_results``."""
    cols = row.nonzero().squeeze(1).tolist()
    words = []
    for c in cols[:most]:
        word = str(c) if c < n else f"{name} ends"
        if c >= n and float(end_values[c - n]) != 0.0:
            word += f" (pseudo-reward {float(end_values[c - n]):g})"
        words.append(word if float(row[c]) == 1.0 else f"{word} (p={float(row[c]):.3g})")
    more = ", ..." if len(cols) > most else ""
    return "{" + ", ".join(words) + more + "}"


# --------------------------------------------------------------------------- helpers
def _ids(rows: torch.Tensor) -> torch.Tensor:
    """Index ``[N]`` of each distinct row of ``rows [N, K]`` (floats compared to 1e-9)."""
    if rows.dim() == 1:
        rows = rows[:, None]
    return torch.unique(rows.to(F64).round(decimals=9), dim=0, return_inverse=True)[1]


def _children(g: TaskGraph, i: int) -> list[int]:
    return g.node_children[i, : int(g.node_n_children[i])].tolist()


def _primitives(g: TaskGraph) -> list[int]:
    return g.node_is_primitive.nonzero().squeeze(1).tolist()


def _subtree(g: TaskGraph, i: int) -> list[int]:
    """``i`` and every node below it."""
    seen, todo = set(), [i]
    while todo:
        k = todo.pop()
        if k not in seen:
            seen.add(k)
            todo += _children(g, k)
    return sorted(seen)
