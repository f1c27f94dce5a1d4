"""Exact dynamic programming for small finite models: the ground truth learners are tested on.

Inputs are a ``TaskGraph`` and a ``FiniteModel``: transition probabilities ``P [S, A, S]``,
rewards ``r [S, A]`` and every full state's observation fields, so subtask predicates and
abstractions are evaluated for all states at once. All tables are float64 tensors.

**Decision states.** ``x = (k, s)``: non-primitive instance ``k`` is on top of the Task-Stack
after popping, in full state ``s``. An instance is a root path, so ``k`` is the whole stack
(the joint state ``X = Omega x S`` of Definition 3.6). From ``x`` the policy pushes children
(no time passes) down to a primitive ``p``; after its step to ``s'``, the shallowest instance of
``p``'s path that ended at ``s'`` (terminated, or ``p`` itself) pops with everything it called
(Section 3.2), and its parent is the next top. Only decision states reachable from the root at
the start states under *some* hierarchical policy are kept: that drops combinations the
hierarchy can never produce (e.g. a delivery subtask running with the other part on board).

**Policies** are tables ``[n_instances, max_states]`` of child slots per (instance, abstract
state) (``instance_table`` expands per-subtask tables). Where the table's child is not
available the first available child is taken (``TablePolicy`` does the same in the executor).

Functions:

- ``markov_chain_gain``: gain of every state of a finite Markov chain (multichain: each
  recurrent class has its own gain ``pi_C r``; transient states mix them by absorption).
- ``flatten``, ``policy_gain``, ``policy_value``: a hierarchical policy as a Markov chain over
  decision states; its global gain (Eq. 4.1) or its (discounted) value until the root ends.
- ``flat_optimal``: best gain over stationary policies of the flat MDP (relative value iteration).
- ``hierarchically_optimal``: best global gain over policies consistent with the hierarchy
  (Definition 3.3, Eq. 4.2): relative value iteration over decision states, where a decision is
  a primitive path through available children.
- ``recursively_optimal``: bottom-up, each subtask optimises its own criterion given its
  children's policies (Definition 3.4): the projected value (Definition 3.5, Eq. 3.3), i.e.
  total reward until it terminates, discounted by ``gamma`` (1: undiscounted) for non-root
  subtasks (what MAXQ-Q learns), and the gain of the root's SMDP (Section 4.2.1) for a continuing
  root. RAR (Section 4.2.2) instead maximises each subtask's own gain ``E[R]/E[N]`` per
  invocation under its start distribution; both prefer shorter invocations when a subtask ends
  with a positive reward (e.g. a delivery), but for subtasks whose every step costs the same
  the gain is the same for all terminating policies, so RAR is indifferent where this
  criterion (and HH-learning's, reward minus a gain above -1 per step) picks the shortest way.
  Children are modelled as executed inside the parent: they also stop where the parent ends.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import torch
from tensordict import TensorDict

from hrl_torch.graph import GraphError, StepContext, TaskGraph

F64 = torch.float64


@dataclass(frozen=True)
class SolverOptions:
    """Iteration settings shared by the solvers.

    Attributes:
        tau: aperiodicity transform ``h + tau (T h - h)`` of relative value iteration.
        tol: stop when the span of ``T h - h`` (value iteration: the change) is below this.
        max_iter: give up (``RuntimeError``) after this many sweeps.
    """

    tau: float = 0.5
    tol: float = 1e-10
    max_iter: int = 100_000


@dataclass
class FiniteModel:
    """A finite MDP as tables: ``transition [S, A, S]``, ``reward [S, A]``, ``observations [S]``."""

    transition: torch.Tensor
    reward: torch.Tensor
    observations: TensorDict

    @classmethod
    def from_tables(cls, transition, reward, decode: Callable) -> FiniteModel:
        """Build from ``[S, A]`` next states (deterministic) or ``[S, A, S]`` probabilities.

        ``decode(states [S]) -> dict`` gives the observation fields the graph reads.
        """
        if transition.dtype == torch.long:
            transition = torch.nn.functional.one_hot(transition, transition.shape[0])
        n = transition.shape[0]
        obs = TensorDict(decode(torch.arange(n)), batch_size=[n])
        return cls(transition.to(F64), reward.to(F64), obs)

    @property
    def n_states(self) -> int:
        """Number of full states ``S``."""
        return self.transition.shape[0]

    def with_reward(self, reward: torch.Tensor) -> FiniteModel:
        """The same dynamics with another reward table (e.g. throughput weights)."""
        return replace(self, reward=reward.to(F64))


# --------------------------------------------------------------------------- Markov chains
@dataclass
class ChainGain:
    """Gains of a Markov chain.

    Attributes:
        gain: ``[N]`` gain from every state.
        recurrent_class: ``[N]`` class of every recurrent state, -1 for transient ones.
        class_gain: ``[C]`` gain of every recurrent class.
    """

    gain: torch.Tensor
    recurrent_class: torch.Tensor
    class_gain: torch.Tensor


def markov_chain_gain(transition: torch.Tensor, reward: torch.Tensor) -> ChainGain:
    """Gain ``P* r`` of a finite chain ``transition [N, N]``, ``reward [N]`` (Eq. 4.1)."""
    p, r = transition.to(F64), reward.to(F64)
    n = p.shape[0]
    reach = (p > 0) | torch.eye(n, dtype=torch.bool)
    while True:  # transitive closure by squaring
        wider = (reach.float() @ reach.float()) > 0
        if torch.equal(wider, reach):
            break
        reach = wider
    recurrent = ~(reach & ~reach.T).any(1)  # every state it reaches reaches it back
    rep = reach.float().argmax(1)  # smallest reachable index: the class of a recurrent state
    reps = torch.unique(rep[recurrent])
    label = torch.where(recurrent, torch.searchsorted(reps, rep), -1)
    rec = recurrent.nonzero().squeeze(1)
    # stationary distributions of all classes at once: pi (I - P) = 0, one sum-to-1 per class
    a = torch.eye(len(rec), dtype=F64) - p[rec][:, rec].T
    b = torch.zeros(len(rec), dtype=F64)
    first = torch.searchsorted(rec, reps)
    a[first] = (label[rec][None, :] == torch.arange(len(reps))[:, None]).to(F64)
    b[first] = 1.0
    pi = torch.linalg.solve(a, b)
    class_gain = torch.zeros(len(reps), dtype=F64).index_add_(0, label[rec], pi * r[rec])
    gain = torch.zeros(n, dtype=F64)
    gain[rec] = class_gain[label[rec]]
    tr = (~recurrent).nonzero().squeeze(1)
    if len(tr):  # transient states: absorption into the classes
        rhs = p[tr][:, rec] @ gain[rec]
        gain[tr] = torch.linalg.solve(torch.eye(len(tr), dtype=F64) - p[tr][:, tr], rhs)
    return ChainGain(gain, label, class_gain)


def _first_best(q: torch.Tensor, ok: torch.Tensor, dim: int, tol: float):
    """Max over ``dim`` of ``q`` where ``ok`` and the first index within ``tol`` of it."""
    q = q.masked_fill(~ok, -torch.inf)
    best = q.amax(dim)
    return best, (q >= best.unsqueeze(dim) - tol).to(F64).argmax(dim)


def _rvi(bellman, h: torch.Tensor, live: torch.Tensor, opt: SolverOptions):
    """Relative value iteration with the aperiodicity transform ``h + tau (T h - h)``.

    ``bellman(h)`` returns ``(T h, ...)``. Returns ``(h, bellman(h), (lo, hi))`` where
    ``lo <= g* <= hi`` are the span bounds ``min / max (T h - h)`` over the live states
    (Puterman 1994, Theorem 8.5.5).
    """
    ref = int(live.flatten().nonzero()[0])
    for _ in range(opt.max_iter):
        out = bellman(h)
        diff = (out[0] - h)[live]
        lo, hi = float(diff.min()), float(diff.max())
        if hi - lo <= opt.tol:
            return h, out, (lo, hi)
        h = h + opt.tau * (out[0] - h)
        h = torch.where(live, h - h.flatten()[ref], 0.0)
    raise RuntimeError(f"relative value iteration: span {hi - lo:.3g} > {opt.tol} after "
                       f"{opt.max_iter} sweeps (is the optimal gain the same from every state?)")


@dataclass
class FlatResult:
    """Optimal gain (``gain``, within ``gain_bounds``), bias ``[S]`` and greedy policy ``[S]``."""

    gain: float
    gain_bounds: tuple[float, float]
    bias: torch.Tensor
    policy: torch.Tensor


def _table_rvi(p, r, ok, live, opt: SolverOptions) -> FlatResult:
    """RVI on ``p [S, C, S]``, ``r [S, C]`` with the choices ``ok [S, C]``."""

    def bellman(h):
        return _first_best(r + torch.einsum("sct,t->sc", p, h), ok, 1, 1e-9)

    h, (_, policy), (lo, hi) = _rvi(bellman, torch.zeros(p.shape[0], dtype=F64), live, opt)
    return FlatResult((lo + hi) / 2, (lo, hi), h, policy)


def flat_optimal(model: FiniteModel, options: SolverOptions = SolverOptions()) -> FlatResult:
    """Best gain of the flat MDP over stationary policies (communicating models)."""
    ok = torch.ones(model.reward.shape, dtype=torch.bool)
    live = torch.ones(model.n_states, dtype=torch.bool)
    return _table_rvi(model.transition, model.reward, ok, live, options)


# --------------------------------------------------------------------------- the unrolled hierarchy
class _Unrolled:
    """A task graph evaluated on every full state: availability, pops, reachable decision states."""

    def __init__(self, graph: TaskGraph, model: FiniteModel, starts: torch.Tensor | None) -> None:
        g, n = graph, model.n_states
        self.graph, self.model, self.n = g, model, n
        ctx = g.context(model.observations)
        self.abstract = ctx.abstract.T  # [n_nodes, S]
        self.term = ctx.terminated.T  # [n_nodes, S]
        has_child = ctx.available.any(-1)  # [S, n_nodes]
        kids = g.node_children.clamp_min(0)
        self.ok_node = (ctx.available & (has_child[:, kids] | g.node_is_primitive[kids]))
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
        self.levels = [k for d in range(int(depths.max()), -1, -1)
                       if len(k := ((depths == d) & ~self.is_prim).nonzero().squeeze(1))]
        if starts is not None and starts.dtype != torch.bool:
            starts = torch.zeros(n, dtype=torch.bool).index_fill_(0, starts.long(), True)
        root_ok = valid[0] if starts is None else valid[0] & starts
        self.reach = self._reachable(valid, root_ok)
        self.node_reach = torch.zeros(g.n_nodes, n).index_add_(
            0, inode, self.reach.float()) > 0  # decision states of every subtask

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
            raise GraphError(f"{self.graph.instance_path(k)!r} can be on top in state {s} "
                             "with no available child: the hierarchy can get stuck")
        return reached

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
            "snt,nt->ns", prob, after)
        choice = torch.zeros(self.graph.n_instances, n, dtype=torch.long)
        for ks in self.levels:
            value[ks], choice[ks] = _first_best(value[self.children[ks]], self.ok[ks], 1, tol)
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


def _flatten(u: _Unrolled, choice: torch.Tensor) -> FlatChain:
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
        1, col.clamp_min(0), torch.where(col >= 0, prob, 0.0))
    end = torch.where(top < 0, prob, 0.0).sum(1)
    return FlatChain(p, u.model.reward[state, action], end, inst, state, index)


def flatten(graph: TaskGraph, model: FiniteModel, table: torch.Tensor,
            starts: torch.Tensor | None = None) -> FlatChain:
    """The Markov chain of ``table`` over reachable decision states."""
    u = _Unrolled(graph, model, starts)
    return _flatten(u, u.resolve(table))


def _start_values(chain: FlatChain, values: torch.Tensor) -> torch.Tensor:
    """Values at ``(root, s)`` for every full state (NaN where the root cannot start)."""
    row = chain.index[0]
    return torch.where(row >= 0, values[row.clamp_min(0)], torch.nan)


def policy_gain(graph: TaskGraph, model: FiniteModel, table: torch.Tensor,
                starts: torch.Tensor | None = None) -> torch.Tensor:
    """Global gain (Eq. 4.1) of a hierarchical policy from each start state ``[S]``.

    NaN where the root cannot start (not a start state, or no available child there).
    """
    chain = flatten(graph, model, table, starts)
    return _start_values(chain, markov_chain_gain(chain.transition, chain.reward).gain)


def policy_value(graph: TaskGraph, model: FiniteModel, table: torch.Tensor, gamma: float = 1.0,
                 starts: torch.Tensor | None = None) -> torch.Tensor:
    """Expected ``gamma``-discounted reward until the root ends, from each start state ``[S]``."""
    chain = flatten(graph, model, table, starts)
    n = len(chain.reward)
    v = torch.linalg.solve(torch.eye(n, dtype=F64) - gamma * chain.transition, chain.reward)
    return _start_values(chain, v)


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
    graph: TaskGraph, model: FiniteModel, gamma: float = 1.0, starts: torch.Tensor | None = None,
    options: SolverOptions = SolverOptions(),
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
    u = _Unrolled(graph, model, starts)
    h = torch.zeros(graph.n_instances, u.n, dtype=F64)
    if not bool(u.term[graph.root].any()):
        h, (_, choice, q), bounds = _rvi(u.backup, h, u.reach, options)
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
    chain = _flatten(u, u.resolve(table))
    exact = _start_values(chain, markov_chain_gain(chain.transition, chain.reward).gain)
    value = torch.where(u.reach[0], h[0], torch.nan)
    return HierarchicalResult(gain, bounds, value, choice, table, consistent, q, exact)


@dataclass
class RecursiveResult:
    """A recursively optimal policy (one policy per subtask, shared by all its instances).

    Attributes:
        choice: ``[n_nodes, S]`` child slot per decision state of every subtask.
        table: ``[n_nodes, max_states]`` per abstract state (``consistent`` as above); run it
            with ``instance_table``.
        value: ``[n_nodes, S]`` projected value (bias at a continuing root).
        q: ``[n_nodes, W, S]`` projected value of each child (SMDP value at the root).
        root_gain: gain of the root's SMDP given its children (continuing root).
        gain: ``[S]`` exact global gain of ``table`` from each start state.
    """

    choice: torch.Tensor
    table: torch.Tensor
    consistent: torch.Tensor
    value: torch.Tensor
    q: torch.Tensor
    root_gain: float
    gain: torch.Tensor


def _model(u: _Unrolled, node: int, stop: torch.Tensor, choice: torch.Tensor, gamma: float):
    """What running ``node`` with ``choice`` until it or a caller (``stop [S]``) ends yields.

    Returns the expected discounted reward ``[S]``, steps ``[S]`` (meaningful for
    ``gamma == 1``) and the ``gamma^N``-weighted exit distribution ``[S, S]``. States where
    ``node`` is never on top count as exits (an ancestor always aborts it there).
    """
    g, m = u.graph, u.model
    if bool(g.node_is_primitive[node]):
        a = int(g.node_action[node])
        return m.reward[:, a], torch.ones(u.n, dtype=F64), gamma * m.transition[:, a]
    stop = stop | u.term[node]
    r, y, p = _children_models(u, node, stop, choice, gamma)
    pick, states = choice[node].clamp(max=len(r) - 1), torch.arange(u.n)
    r, y, p = r[pick, states], y[pick, states], p[pick, states]
    going = ~stop & u.node_reach[node]
    run = going.nonzero().squeeze(1)
    out_r, out_y, out_p = torch.zeros(u.n, dtype=F64), torch.zeros(u.n, dtype=F64), torch.eye(
        u.n, dtype=F64)
    if len(run):
        rhs = torch.cat([r[run, None], y[run, None], p[run] * ~going], 1)
        try:
            sol = torch.linalg.solve(torch.eye(len(run), dtype=F64) - p[run][:, run], rhs)
        except RuntimeError as err:
            raise GraphError(f"the policy of {g.names[node]!r} does not always terminate") from err
        out_r[run], out_y[run], out_p[run] = sol[:, 0], sol[:, 1], sol[:, 2:]
    return out_r, out_y, out_p


def _children_models(u: _Unrolled, node: int, stop: torch.Tensor, choice: torch.Tensor,
                     gamma: float):
    """``_model`` of every child of ``node``, stacked: ``[C, S]``, ``[C, S]``, ``[C, S, S]``."""
    kids = u.graph.node_children[node, : int(u.graph.node_n_children[node])].tolist()
    parts = zip(*(_model(u, c, stop, choice, gamma) for c in kids), strict=True)
    return tuple(torch.stack(x) for x in parts)


def recursively_optimal(
    graph: TaskGraph, model: FiniteModel, gamma: float = 1.0, starts: torch.Tensor | None = None,
    options: SolverOptions = SolverOptions(),
) -> RecursiveResult:
    """Bottom-up recursive optimisation (the criteria are in the module docstring).

    Args:
        graph: the task graph; its policies are optimised per subtask (shared by instances).
        model: the finite model.
        gamma: discount of the non-root subtasks' projected values (and of an episodic root).
        starts: start states ``[S]`` (bool or indices) of the root (default: all).
        options: iteration settings.
    """
    g, u = graph, _Unrolled(graph, model, starts)
    n, width = u.n, g.max_children
    choice = torch.zeros(g.n_nodes, n, dtype=torch.long)
    value = torch.zeros(g.n_nodes, n, dtype=F64)
    q = torch.full((g.n_nodes, width, n), -torch.inf, dtype=F64)
    root_gain = float("nan")
    for i in sorted(g.subtasks(), key=lambda k: int(g.node_height[k])):
        continuing = i == g.root and not bool(u.term[i].any())
        r, y, p = _children_models(u, i, u.term[i], choice, 1.0 if continuing else gamma)
        stop = u.term[i] | ~u.node_reach[i]  # where ``i`` is not deciding: exits, worth 0
        ok = u.ok_node[i, : len(r)] & ~stop  # [C, S]
        if continuing:
            if float((p[:, :, stop].sum(-1) * ok).max()) > 1e-9:
                raise GraphError("a child of the root exits where the root cannot continue")
            eye = torch.eye(n, dtype=F64)
            y = torch.where(ok, y, 1.0)
            smdp = torch.where(ok[..., None], eye + (p - eye) / y[..., None], eye)  # [C, S, S']
            res = _table_rvi(smdp.transpose(0, 1), torch.where(ok, r / y, 0.0).T, ok.T, ~stop,
                             options)  # data transformation: same gain as the SMDP
            root_gain, choice[i], value[i] = res.gain, res.policy, res.bias
            qi = r - res.gain * y + p @ res.bias
        else:
            v = torch.zeros(n, dtype=F64)
            for _ in range(options.max_iter):
                qi = r + p @ v  # exits into stop states are worth 0: v is 0 there
                best, arg = _first_best(qi, ok, 0, 1e-9)
                v, change = torch.where(stop, 0.0, best), v
                if float((v - change).abs().max()) <= options.tol:
                    break
            else:
                raise RuntimeError(f"value iteration of {g.names[i]!r} did not converge")
            choice[i], value[i] = arg, v
        q[i, : len(r)] = qi.masked_fill(~ok, -torch.inf)
    table, consistent = u.project(q, u.node_reach, torch.arange(g.n_nodes))
    chain = _flatten(u, u.resolve(instance_table(g, table)))
    gain = _start_values(chain, markov_chain_gain(chain.transition, chain.reward).gain)
    return RecursiveResult(choice, table, consistent, value, q, root_gain, gain)
