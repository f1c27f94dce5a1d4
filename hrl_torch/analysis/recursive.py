"""The recursively optimal policy: each subtask optimises its criterion given its children.

See the package docstring of ``hrl_torch.analysis`` for the criteria.
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
    table_rvi,
)
from hrl_torch.analysis.hierarchy import Unrolled, flatten_unrolled, instance_table, start_values
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError


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


def _model(u: Unrolled, node: int, stop: torch.Tensor, choice: torch.Tensor, gamma: float):
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
    out_r, out_y, out_p = (
        torch.zeros(u.n, dtype=F64),
        torch.zeros(u.n, dtype=F64),
        torch.eye(u.n, dtype=F64),
    )
    if len(run):
        rhs = torch.cat([r[run, None], y[run, None], p[run] * ~going], 1)
        try:
            sol = torch.linalg.solve(torch.eye(len(run), dtype=F64) - p[run][:, run], rhs)
        except RuntimeError as err:
            raise GraphError(f"the policy of {g.names[node]!r} does not always terminate") from err
        out_r[run], out_y[run], out_p[run] = sol[:, 0], sol[:, 1], sol[:, 2:]
    return out_r, out_y, out_p


def _children_models(
    u: Unrolled, node: int, stop: torch.Tensor, choice: torch.Tensor, gamma: float
):
    """``_model`` of every child of ``node``, stacked: ``[C, S]``, ``[C, S]``, ``[C, S, S]``."""
    kids = u.graph.node_children[node, : int(u.graph.node_n_children[node])].tolist()
    parts = zip(*(_model(u, c, stop, choice, gamma) for c in kids), strict=True)
    return tuple(torch.stack(x) for x in parts)


def recursively_optimal(
    graph: TaskGraph,
    model: FiniteModel,
    gamma: float = 1.0,
    starts: torch.Tensor | None = None,
    options: SolverOptions = DEFAULT_OPTIONS,
) -> RecursiveResult:
    """Bottom-up recursive optimisation (the criteria are in the module docstring).

    Args:
        graph: the task graph; its policies are optimised per subtask (shared by instances).
        model: the finite model.
        gamma: discount of the non-root subtasks' projected values (and of an episodic root).
        starts: start states ``[S]`` (bool or indices) of the root (default: all).
        options: iteration settings.
    """
    g, u = graph, Unrolled(graph, model, starts)
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
            res = table_rvi(
                smdp.transpose(0, 1), torch.where(ok, r / y, 0.0).T, ok.T, ~stop, options
            )  # data transformation: same gain as the SMDP
            root_gain, choice[i], value[i] = res.gain, res.policy, res.bias
            qi = r - res.gain * y + p @ res.bias
        else:
            v = torch.zeros(n, dtype=F64)
            for _ in range(options.max_iter):
                qi = r + p @ v  # exits into stop states are worth 0: v is 0 there
                best, arg = first_best(qi, ok, 0, 1e-9)
                v, change = torch.where(stop, 0.0, best), v
                if float((v - change).abs().max()) <= options.tol:
                    break
            else:
                raise RuntimeError(f"value iteration of {g.names[i]!r} did not converge")
            choice[i], value[i] = arg, v
        q[i, : len(r)] = qi.masked_fill(~ok, -torch.inf)
    table, consistent = u.project(q, u.node_reach, torch.arange(g.n_nodes))
    chain = flatten_unrolled(u, u.resolve(instance_table(g, table)))
    gain = start_values(chain, markov_chain_gain(chain.transition, chain.reward).gain)
    return RecursiveResult(choice, table, consistent, value, q, root_gain, gain)
