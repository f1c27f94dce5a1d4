"""Hierarchical policies as Markov chains over decision states; the hierarchical optimum.

See the package docstring of ``hrl_torch.analysis`` for the decision states and criteria.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hrl_torch.analysis.chains import (
    DEFAULT_OPTIONS,
    F64,
    FiniteModel,
    SolverOptions,
    first_best,
    markov_chain_gain,
    rvi,
)
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError


class Unrolled:
    """A task graph evaluated on every full state: availability, pops, reachable decision states."""

    def __init__(self, graph: TaskGraph, model: FiniteModel, starts: torch.Tensor | None) -> None:
        g, n = graph, model.n_states
        self.graph, self.model, self.n = g, model, n
        ctx = g.context(model.observations)
        self.abstract = ctx.abstract.T  # [n_nodes, S]
        self.term = ctx.terminated.T  # [n_nodes, S]
        self.blocked = ctx.blocked.T  # [n_nodes, S]: terminal states (events excluded)
        has_child = ctx.available.any(-1)  # [S, n_nodes]
        kids = g.node_children.clamp_min(0)
        self.ok_node = ctx.available & (has_child[:, kids] | g.node_is_primitive[kids])
        self.ok_node = self.ok_node.permute(1, 2, 0)  # [n_nodes, W, S]: child usable at s
        inode, parent = g.inst_node, g.inst_parent
        self.is_prim = g.node_is_primitive[inode]
        self.ok = self.ok_node[inode]  # [I, W, S]
        self.available = ctx.available.permute(1, 2, 0)[inode]  # [I, W, S]
        self.children = g.inst_children.clamp_min(0)
        n_inst = g.n_instances
        path_term = torch.zeros(n_inst, n, dtype=torch.bool)
        first_end = torch.full((n_inst, n), -1)
        for k in range(n_inst):  # instances are breadth first: parents come first
            ended = torch.ones(n, dtype=torch.bool) if self.is_prim[k] else self.term[inode[k]]
            above = first_end[parent[k]] if k else torch.full((n,), -1)
            first_end[k] = torch.where(above >= 0, above, torch.where(ended, k, -1))
            own = ended & ~self.is_prim[k]
            path_term[k] = (path_term[parent[k]] | own) if k else own
        valid = ~self.is_prim[:, None] & ~path_term & has_child[:, inode].T
        self.pop_top = parent[first_end.clamp_min(0)]  # next top after a primitive (-1: root ended)
        self.prims = self.is_prim.nonzero().squeeze(1)
        self.actions = g.node_action[inode[self.prims]]
        depths = g.inst_depth
        self.levels = [
            k
            for d in range(int(depths.max()), -1, -1)
            if len(k := ((depths == d) & ~self.is_prim).nonzero().squeeze(1))
        ]
        root_ok = valid[0] & _start_mask(starts, n)
        self.reach = self._reachable(valid, root_ok)
        self.node_reach = (
            torch.zeros(g.n_nodes, n).index_add_(0, inode, self.reach.float()) > 0
        )  # decision states of every subtask

    def _reachable(self, valid: torch.Tensor, start: torch.Tensor) -> torch.Tensor:
        """Decision states reachable from ``(root, start)`` under any hierarchical policy."""
        n, n_inst, n_prim = self.n, self.graph.n_instances, len(self.prims)
        push = torch.zeros(n_inst, n_prim, n, dtype=torch.bool)  # p can end up on top of k at s
        push[self.prims, torch.arange(n_prim)] = True
        for ks in self.levels:
            push[ks] = (push[self.children[ks]] & self.ok[ks][:, :, None, :]).any(1)
        s_all, a_all, t_all = (self.model.transition > 0).nonzero(as_tuple=True)
        src, dst = [], []
        for j, p in enumerate(self.prims.tolist()):  # edges (k, s) -> (top after p, s')
            sel = a_all == self.actions[j]
            s, t = s_all[sel], t_all[sel]
            top = self.pop_top[p, t]
            k, e = (push[:, j, s] & (top >= 0)).nonzero(as_tuple=True)
            src.append(k * n + s[e])
            dst.append(top[e] * n + t[e])
        src, dst = torch.cat(src), torch.cat(dst)
        reached = torch.zeros(n_inst * n, dtype=torch.bool)
        reached[:n] = start
        while True:
            wider = reached.clone()
            wider[dst[reached[src]]] = True
            if torch.equal(wider, reached):
                break
            reached = wider
        reached = reached.view(n_inst, n)
        for k in range(n_inst):  # entry states: a pushed child is on top before it acts
            for slot, child in enumerate(self.children[k].tolist()):
                if not self.is_prim[child]:
                    reached[child] |= reached[k] & self.available[k, slot]
        if bool((reached & ~valid).any()):
            k, s = (int(v) for v in (reached & ~valid).nonzero()[0])
            raise GraphError(self._stuck_message(k, s))
        return reached

    def _stuck_message(self, k: int, s: int) -> str:
        """Why instance ``k`` has no usable child in state ``s``, and what to do about it."""
        g = self.graph
        node = int(g.inst_node[k])
        reasons = []
        for slot, child in enumerate(g.node_children[node, : int(g.node_n_children[node])]):
            if bool(self.blocked[child, s]):
                why = "terminated"
            elif not bool(self.available[k, slot, s]):
                why = "not initiable or masked"
            else:
                why = "none of its own children available"
            reasons.append(f"{g.names[int(child)]}: {why}")
        where = f"{g.instance_path(k)!r} can be on top in state {s}, where no child is usable"
        where += f" ({', '.join(reasons)})"
        if k == 0:
            return (
                f"{where}. An episodic analysis needs a `terminated` predicate on the root that "
                f"holds where the episode ends (is state {s} such a state?); the env's own "
                "episode end is not part of the finite model"
            )
        return f"{where}: the hierarchy can get stuck"

    def resolve(self, table: torch.Tensor) -> torch.Tensor:
        """Child slot ``[I, S]`` of an abstract-state table (first usable child if unusable)."""
        inode = self.graph.inst_node
        want = table.long().gather(1, self.abstract[inode]).clamp(0, self.ok.shape[1] - 1)
        usable = self.ok.gather(1, want[:, None, :]).squeeze(1)
        return torch.where(usable, want, self.ok.to(F64).argmax(1))

    def pushed(self, choice: torch.Tensor) -> torch.Tensor:
        """Primitive instance ``[I, S]`` reached by pushing ``choice`` from each instance."""
        out = torch.arange(self.graph.n_instances)[:, None].expand(-1, self.n).clone()
        states = torch.arange(self.n)
        for ks in self.levels:
            child = self.children[ks].gather(1, choice[ks])
            out[ks] = out[child, states]
        return out

    def backup(self, h: torch.Tensor, gamma: float = 1.0, tol: float = 1e-9):
        """Greedy one-step lookahead ``(T h [I, S], choice [I, S], child values [I, W, S])``."""
        n = self.n
        top = self.pop_top[self.prims]
        after = torch.where(top >= 0, h[top.clamp_min(0), torch.arange(n)], 0.0)
        prob = self.model.transition[:, self.actions, :]
        value = torch.full((self.graph.n_instances, n), -torch.inf, dtype=F64)
        value[self.prims] = self.model.reward[:, self.actions].T + gamma * torch.einsum(
            "snt,nt->ns", prob, after
        )
        choice = torch.zeros(self.graph.n_instances, n, dtype=torch.long)
        for ks in self.levels:
            value[ks], choice[ks] = first_best(value[self.children[ks]], self.ok[ks], 1, tol)
        q = value[self.children].masked_fill(~self.ok, -torch.inf)
        return torch.where(self.reach, value, 0.0), choice, q

    def project(self, q, relevant, node_of_row, tol: float = 1e-7):
        """Abstract-state tables ``[rows, max_states]`` from child values ``q [rows, W, S]``.

        Per abstract state, the child whose worst regret over the ``relevant`` full states is
        smallest (the first on ties); ``consistent`` says it is optimal at all of them.
        """
        g = self.graph
        best = q.amax(1, keepdim=True)
        regret = torch.where(q >= best - tol, 0.0, q - best)
        regret = torch.where(relevant[:, None, :], regret, torch.inf)
        width = int(g.node_n_states.max())
        index = self.abstract[node_of_row][:, None, :].expand_as(regret)
        score = torch.full((*regret.shape[:2], width), torch.inf, dtype=F64)
        score = score.scatter_reduce(2, index, regret, "amin")  # [rows, W, width]
        table = score.argmax(1)
        consistent = score.gather(1, table[:, None]).squeeze(1) >= 0
        return table, consistent


# --------------------------------------------------------------------------- policies
def instance_table(graph: TaskGraph, node_table: torch.Tensor) -> torch.Tensor:
    """Per-instance table from a per-subtask table ``[n_nodes, max_states]`` (shared policies)."""
    return node_table[graph.inst_node]


@dataclass
class FlatChain:
    """A hierarchical policy as a Markov chain over decision states ``x = (inst[x], state[x])``.

    Attributes:
        transition: ``[N, N]`` one primitive step, pushes and pops included.
        reward: ``[N]`` reward of that step.
        end: ``[N]`` probability that the root ends at that step (episodic roots).
        inst, state: ``[N]`` the instance on top and the full state of every row.
        index: ``[I, S]`` row of every decision state (-1: not reachable).
    """

    transition: torch.Tensor
    reward: torch.Tensor
    end: torch.Tensor
    inst: torch.Tensor
    state: torch.Tensor
    index: torch.Tensor


def flatten_unrolled(u: Unrolled, choice: torch.Tensor) -> FlatChain:
    """The Markov chain of the unrolled hierarchy ``u`` under the choices ``choice``."""
    inst, state = u.reach.nonzero(as_tuple=True)
    index = torch.full(u.reach.shape, -1)
    index[inst, state] = torch.arange(len(inst))
    prim = u.pushed(choice)[inst, state]
    action = u.graph.node_action[u.graph.inst_node[prim]]
    prim_row = torch.searchsorted(u.prims, prim)
    top = u.pop_top[u.prims][prim_row]  # [N, S']
    col = torch.where(top >= 0, index[top.clamp_min(0), torch.arange(u.n)], -1)
    prob = u.model.transition[state, action]
    if bool(((prob > 0) & (top >= 0) & (col < 0)).any()):
        raise GraphError("the policy leaves the reachable decision states (a stuck subtask?)")
    p = torch.zeros(len(inst), len(inst), dtype=F64).scatter_add_(
        1, col.clamp_min(0), torch.where(col >= 0, prob, 0.0)
    )
    end = torch.where(top < 0, prob, 0.0).sum(1)
    return FlatChain(p, u.model.reward[state, action], end, inst, state, index)


def flatten(
    graph: TaskGraph, model: FiniteModel, table: torch.Tensor, starts: torch.Tensor | None = None
) -> FlatChain:
    """The Markov chain of ``table`` over reachable decision states."""
    u = Unrolled(graph, model, starts)
    return flatten_unrolled(u, u.resolve(table))


def start_values(chain: FlatChain, values: torch.Tensor) -> torch.Tensor:
    """Values at ``(root, s)`` for every full state (NaN where the root cannot start)."""
    row = chain.index[0]
    return torch.where(row >= 0, values[row.clamp_min(0)], torch.nan)


def policy_gain(
    graph: TaskGraph, model: FiniteModel, table: torch.Tensor, starts: torch.Tensor | None = None
) -> torch.Tensor:
    """Global gain (Eq. 4.1) of a hierarchical policy from each start state ``[S]``.

    NaN where the root cannot start (not a start state, or no available child there).
    """
    chain = flatten(graph, model, table, starts)
    return start_values(chain, markov_chain_gain(chain.transition, chain.reward).gain)


def policy_value(
    graph: TaskGraph,
    model: FiniteModel,
    table: torch.Tensor,
    gamma: float = 1.0,
    starts: torch.Tensor | None = None,
) -> torch.Tensor:
    """Expected ``gamma``-discounted reward until the root ends, from each start state ``[S]``.

    Solved over the decision states the policy reaches from the starts only, so what the table
    does elsewhere (e.g. loop) does not matter. NaN where the root does not start.

    Raises:
        ValueError: ``gamma == 1`` and the root never ends from some reached decision state
            (the message names the instance and the state where the policy loops).
    """
    chain = flatten(graph, model, table, starts)
    start_rows = chain.index[0][_start_mask(starts, model.n_states)]
    start_rows = start_rows[start_rows >= 0]
    src, dst = (chain.transition > 0).nonzero(as_tuple=True)
    reached = _closure(src, dst, start_rows, len(chain.reward))
    if gamma >= 1.0:
        can_end = _closure(dst, src, (chain.end > 0).nonzero().squeeze(1), len(chain.reward))
        if bool((reached & ~can_end).any()):
            k, s = _loop_in(chain, reached & ~can_end)
            raise ValueError(
                f"the root never ends under this policy: from a start state it reaches "
                f"{graph.instance_path(k)!r} in state {s}, where it loops (the undiscounted "
                "value is not defined; give a gamma < 1 or a policy that ends)"
            )
    rows = reached.nonzero().squeeze(1)
    p = chain.transition[rows][:, rows]
    v = torch.full_like(chain.reward, torch.nan)
    v[rows] = torch.linalg.solve(torch.eye(len(rows), dtype=F64) - gamma * p, chain.reward[rows])
    return torch.where(_start_mask(starts, model.n_states), start_values(chain, v), torch.nan)


def _start_mask(starts: torch.Tensor | None, n: int) -> torch.Tensor:
    """``starts`` (bool, indices or ``None`` for all) as a ``[n]`` bool mask."""
    if starts is None:
        return torch.ones(n, dtype=torch.bool)
    if starts.dtype == torch.bool:
        return starts
    return torch.zeros(n, dtype=torch.bool).index_fill_(0, starts.long(), True)


def _closure(src: torch.Tensor, dst: torch.Tensor, seeds: torch.Tensor, n: int) -> torch.Tensor:
    """Rows reachable from ``seeds`` along the edges ``src -> dst`` (``[n]`` bool)."""
    reached = torch.zeros(n, dtype=torch.bool)
    reached[seeds] = True
    while True:
        wider = reached.clone()
        wider[dst[reached[src]]] = True
        if torch.equal(wider, reached):
            return reached
        reached = wider


def _loop_in(chain: FlatChain, trapped: torch.Tensor) -> tuple[int, int]:
    """``(instance, state)`` on a cycle inside ``trapped``, rows that can never end the root."""
    row = int(trapped.nonzero()[0])
    for _ in range(int(trapped.sum())):  # every trapped row moves to a trapped row
        row = int((chain.transition[row] * trapped).argmax())
    return int(chain.inst[row]), int(chain.state[row])


class TablePolicy:
    """Runs an instance table in the ``HierarchicalExecutor`` (exact policies in simulation)."""

    def __init__(self, graph: TaskGraph, table: torch.Tensor) -> None:
        self.graph, self.table = graph, table.long()

    def new_step(self) -> None:
        """Nothing to draw: the policy is deterministic."""

    def select(self, inst, ctx: StepContext, available, step, push=0):
        """Return ``(child slot [B], greedy flag [B])``; unusable choices fall back as above."""
        g = self.graph
        node = g.inst_node[inst.clamp_min(0)]
        want = self.table[inst.clamp_min(0), ctx.abstract.gather(1, node[:, None]).squeeze(1)]
        kids = g.node_children[node].clamp_min(0)
        rows = torch.arange(len(inst))[:, None]
        usable = available & (ctx.available[rows, kids].any(-1) | g.node_is_primitive[kids])
        want = want.clamp(0, usable.shape[1] - 1)
        ok = usable.gather(1, want[:, None]).squeeze(1)
        choice = torch.where(ok, want, usable.float().argmax(1))
        return choice, torch.ones_like(choice, dtype=torch.bool)


# --------------------------------------------------------------------------- optimal policies
@dataclass
class HierarchicalResult:
    """A hierarchically optimal policy.

    Attributes:
        gain: optimal global gain (continuing root; NaN for an episodic root), within
            ``gain_bounds``.
        value: ``[S]`` bias (continuing) or optimal value (episodic) at ``(root, s)``.
        choice: ``[I, S]`` child slot per decision state.
        table: ``[I, max_states]`` the same per abstract state; ``consistent`` says the child is
            optimal at every full state of that abstract state.
        q: ``[I, W, S]`` value of pushing each child.
        policy_gain: ``[S]`` exact global gain of ``table`` from each start state.
    """

    gain: float
    gain_bounds: tuple[float, float]
    value: torch.Tensor
    choice: torch.Tensor
    table: torch.Tensor
    consistent: torch.Tensor
    q: torch.Tensor
    policy_gain: torch.Tensor


def hierarchically_optimal(
    graph: TaskGraph,
    model: FiniteModel,
    gamma: float = 1.0,
    starts: torch.Tensor | None = None,
    options: SolverOptions = DEFAULT_OPTIONS,
) -> HierarchicalResult:
    """Best policy consistent with the hierarchy, the Task-Stack being part of the state.

    Args:
        graph: the task graph; its policies are optimised per instance (per stack context).
        model: the finite model.
        gamma: discount of an episodic root's return (a continuing root maximises the gain,
            Eq. 4.2, by relative value iteration over decision states).
        starts: start states ``[S]`` (bool or indices) of the root (default: all).
        options: iteration settings.
    """
    u = Unrolled(graph, model, starts)
    h = torch.zeros(graph.n_instances, u.n, dtype=F64)
    if not bool(u.term[graph.root].any()):
        h, (_, choice, q), bounds = rvi(u.backup, h, u.reach, options)
        gain = sum(bounds) / 2
    else:
        for _ in range(options.max_iter):
            th, choice, q = u.backup(h, gamma)
            h, change = th, h
            if float((h - change).abs().max()) <= options.tol:
                break
        else:
            raise RuntimeError("value iteration did not converge")
        gain, bounds = float("nan"), (float("nan"), float("nan"))
    table, consistent = u.project(q, u.reach, graph.inst_node)
    chain = flatten_unrolled(u, u.resolve(table))
    exact = start_values(chain, markov_chain_gain(chain.transition, chain.reward).gain)
    value = torch.where(u.reach[0], h[0], torch.nan)
    return HierarchicalResult(gain, bounds, value, choice, table, consistent, q, exact)
