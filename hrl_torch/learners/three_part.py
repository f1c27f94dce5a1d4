"""The three-part value decomposition (Andre and Russell 2002), shared by HDR and HAR.

Tables are per instance (the Task-Stack is part of the state, Section 3.4). For a non-primitive
instance ``i`` in state ``x`` and a child ``a`` (Equations 4.7-4.11; HDR reads them discounted)::

    Q^(i, x, a) = V(a, x) + C(i, x, a)          projected action value (Eq. 4.11)
    Q(i, x, a)  = Q^(i, x, a) + CE(i, x, a)     hierarchical action value (Eq. 4.7): chooses a
    V(i, x)     = Q^(i, x, a*),  a* = argmax_a Q(i, x, a)               (Eq. 4.10)
    W(i, x)     = Q(i, x, a*) where i decides at x, else W(Parent(i), x)

``V(p, x)`` of a primitive is learned; ``W`` is the value of the whole stack above ``i``: what
the external completion of a child that ends at ``x`` continues with.

Updates after child ``a`` of ``i`` ran from ``x`` to ``x'`` taking time ``t`` (primitive steps
``N`` in discrete time, duration ``tau`` in continuous time), with ``a* = argmax Q(i, x', .)``
and ``d(t)`` the discount (``gamma**t`` for HDR, 1 for HAR)::

    C(i, x, a)  <- (1-alpha) C  + alpha d(t) V(i, x')                 Alg. 1 line 17 (0 at T_i)
    CE(i, x, a) <- (1-alpha) CE + alpha d(t) W(Parent(i), x')  x' in T_i     Alg. 1 line 19
                   (1-alpha) CE + alpha d(t) CE(i, x', a*)      otherwise    Alg. 1 line 21
    V(p, x)     <- (1-alpha) V  + alpha target(r, t)               primitive p, Alg. 1 line 5

Line 19 writes ``L(Parent(i), (omega / i, s'), a*)`` with the ``a*`` of line 15 (a child of
``i``); Eq. 4.9 makes it the parent's own choice ``mu_Parent(i)``, i.e. ``W(Parent(i), x')``,
which is what we use. With all-states updating (line 16, "for each x in ChildSeq") every state
``x_k`` the child passed through gets the same targets with ``d`` of the time left after
``x_k``. Subclasses give ``discount`` and the primitive target.
"""

from __future__ import annotations

import torch

from hrl_torch.common.ops import argmax_last, columns, entries, take_flat
from hrl_torch.execution.transitions import LEVEL
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners.base import TabularLearner, finished
from hrl_torch.modules.schedules import Schedule


def three_part_targets(
    discount: torch.Tensor,
    terminal: torch.Tensor,
    v_next: torch.Tensor,
    ce_next: torch.Tensor,
    outer_next: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Completion and external completion targets (Algorithm 1, lines 17-21).

    Args:
        discount: ``d(t)`` (all arguments broadcast together).
        terminal: ``x'`` is terminal for the subtask.
        v_next: ``V(i, x')``, the projected value of the subtask at ``x'``.
        ce_next: ``CE(i, x', a*)``.
        outer_next: ``W(Parent(i), x')``, the value of the stack above the subtask at ``x'``.

    Returns:
        ``(C target, CE target)``.
    """
    zero = torch.zeros((), device=v_next.device)
    completion = discount * torch.where(terminal, zero, v_next)
    external = discount * torch.where(terminal, outer_next, ce_next)
    return completion, external


class ThreePartLearner(TabularLearner):
    """Tables ``C``, ``CE`` (non-primitive instances) and ``V`` (primitive instances).

    Args:
        graph: the task graph (internal rewards are not supported).
        n_learners: population size ``P``.
        alpha: step size (number or schedule).
        gamma: discount factor (passed to the executor; 1 for undiscounted learners).
        all_states: also update every state visited during the child (needs the executor's
            ``record_visited``).
        continuous: measure time by durations ``tau`` (continuous time) instead of primitive
            steps ``N`` (discrete time).
        init: initial completion values ``C``.
        ce_init: initial external completions ``CE`` (default: ``init``).
    """

    uses = frozenset({"parent_inst"})
    value_keys = ("V", "CE", "W", "Q")

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        alpha: float | Schedule = 0.5,
        gamma: float = 1.0,
        all_states: bool = False,
        continuous: bool = False,
        init: float = 0.0,
        ce_init: float | None = None,
    ) -> None:
        super().__init__(graph, n_learners, alpha, gamma, per_instance=True)
        if graph.internal_nodes:
            raise GraphError("three-part learners do not support pseudo or shaping rewards")
        self.all_states = all_states
        self.continuous = continuous
        self.C = self.completion_bank(init)
        self.CE = self.completion_bank(init if ce_init is None else ce_init)
        self.V = self.primitive_bank()
        self.share_store(C=self.C, V=self.V, CE=self.CE)
        self.attach_heads(C=self.C, CE=self.CE, V=self.V)
        depth, parent = graph.inst_depth, graph.inst_parent
        composite = ~graph.node_is_primitive[graph.inst_node]
        # non-primitive instances by depth below the root, for the top-down W
        self._levels = [
            ids
            for d in range(1, int(depth.max()) + 1)
            if len(ids := ((depth == d) & composite).nonzero().squeeze(1))
        ]
        self.register_buffer("_parent", parent.clamp_min(0), persistent=False)

    # ------------------------------------------------------------------ hooks
    def discount(self, t: torch.Tensor) -> torch.Tensor:
        """``d(t)``: how much a value ``t`` time units later counts now."""
        raise NotImplementedError

    def primitive_target(self, batch) -> torch.Tensor:
        """Target of ``V(p, x)`` for the primitive steps of ``batch`` ``[B]``."""
        raise NotImplementedError

    # ------------------------------------------------------------------ values
    def evaluate(self, ctx: StepContext) -> None:
        """Bottom-up ``V``, ``CE(., a*)`` and ``Q(., a*)``; top-down ``W``, for every instance.

        ``ctx.values``: ``V``, ``CE``, ``W`` ``[B, T]``; ``Q`` ``[B, Tc, A]`` (plan order), the
        rows ``V + C + CE`` the choices read.
        """
        blocked, dead, (c, ce) = self.composite_rows(ctx, self.C, self.CE)
        value = self.primitive_values(ctx, self.V)
        ce_best = torch.zeros_like(value)
        full = torch.zeros_like(value)
        q_rows = []
        for ids, kids, unavailable, gone, c_part, ce_part in self.groups(blocked, dead, c, ce):
            projected = take_flat(value, kids) + c_part  # Eq. 4.11
            q = projected + ce_part  # Eq. 4.7
            best = argmax_last(q.masked_fill(unavailable, -torch.inf), keepdim=True)
            for out, rows in ((value, projected), (ce_best, ce_part), (full, q)):
                out.index_copy_(1, ids, rows.gather(-1, best).squeeze(-1).masked_fill(gone, 0.0))
            q_rows.append(q)
        outer = full.clone()  # W: an instance that ended at x hands over to its parent
        for ids in self._levels:
            ended = columns(ctx.terminated, self.layout.table_node[ids])
            outer[:, ids] = torch.where(ended, outer[:, self._parent[ids]], full[:, ids])
        ctx.values["V"] = value
        ctx.values["CE"] = ce_best
        ctx.values["W"] = outer
        ctx.values["Q"] = torch.cat(q_rows, 1)

    # ------------------------------------------------------------------ updates
    def update(self, batch, step: int) -> None:
        """Algorithm 1's updates for every finished child and primitive step in ``batch``.

        One update of the shared store: ``C`` and ``CE`` of every level whose child finished,
        ``V`` of the primitive on its level (``ran``).
        """
        fields = entries(batch)
        level, values = entries(fields[LEVEL]), entries(fields["values"])
        alpha = self.alpha(step)
        table = self.level_table(level)  # tables per instance: the instance
        terminal, ran = level["terminal"], level["ran"]
        valid = finished(level)
        t = self.time_of(batch)
        v_next = values["V"].gather(1, table)
        ce_next = values["CE"].gather(1, table)
        parent = level["parent_inst"]
        outer = values["W"].gather(1, parent.clamp_min(0)).masked_fill(parent < 0, 0.0)
        c_target, ce_target = three_part_targets(self.discount(t), terminal, v_next, ce_next, outer)
        index = self.entry_index(fields["learner"], level, table)
        c_or_v = torch.where(ran, self.primitive_target(batch)[:, None], c_target)  # line 5
        old = self.tables.update(  # lines 17 and 19 / 21, and line 5
            torch.cat([index, index + (self.CE.base - self.C.base)], 1),
            torch.cat([c_or_v, ce_target], 1),
            alpha,
            torch.cat([valid | ran, valid], 1),
            self.rows_distinct(fields["learner"]),
        )
        learner = self.plan.learner_base(fields["learner"], 1, 2)  # [B, 1]
        self.record_td(learner, level["node"], c_target - old[:, : index.shape[1]], valid)
        if self.all_states and "visited_state" in level.keys():
            # line 16: every x in ChildSeq, with the time left after it
            left = t[..., None] - self.time_of(batch, "visited_steps", "visited_time")
            c_k, ce_k = three_part_targets(
                self.discount(left),
                terminal[..., None],
                v_next[..., None],
                ce_next[..., None],
                outer[..., None],
            )
            self.update_visited(batch, table, valid, alpha, [(self.C, c_k), (self.CE, ce_k)])
