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

from hrl_torch.executor import LEVEL, PRIMITIVE
from hrl_torch.exploration import Schedule, masked_argmax
from hrl_torch.graph import GraphError, StepContext, TaskGraph
from hrl_torch.learners.base import TabularLearner


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
        """Bottom-up ``V``, ``CE(., a*)`` and ``Q(., a*)``; top-down ``W``, for every instance."""
        lay = self.layout
        b = ctx.abstract.shape[0]
        value = torch.zeros(b, lay.n_tables, device=ctx.abstract.device)
        ce_best = torch.zeros_like(value)
        full = torch.zeros_like(value)
        prims = lay.groups[0]
        idx = self.V.index(ctx.learner[:, None], prims[None, :], self.table_states(ctx, prims), 0)
        value[:, prims] = self.V.read(idx)
        zero = torch.zeros((), device=value.device)
        for ids in lay.groups[1:]:
            nodes = lay.table_node[ids]
            available = ctx.available[:, nodes]
            projected = value[:, lay.table_children[ids].clamp_min(0)] + self.table_rows(
                self.C, ctx, ids, available
            )  # Eq. 4.11
            ce = self.table_rows(self.CE, ctx, ids, available)
            q = projected + ce  # Eq. 4.7
            best = masked_argmax(q, available).unsqueeze(-1)
            dead = ctx.blocked[:, nodes] | ~available.any(-1)
            value[:, ids] = torch.where(dead, zero, projected.gather(-1, best).squeeze(-1))
            ce_best[:, ids] = torch.where(dead, zero, ce.gather(-1, best).squeeze(-1))
            full[:, ids] = torch.where(dead, zero, q.gather(-1, best).squeeze(-1))
        outer = full.clone()  # W: an instance that ended at x hands over to its parent
        for ids in self._levels:
            ended = ctx.terminated[:, lay.table_node[ids]]
            outer[:, ids] = torch.where(ended, outer[:, self._parent[ids]], full[:, ids])
        ctx.values["V"] = value
        ctx.values["CE"] = ce_best
        ctx.values["W"] = outer

    def action_values(self, inst: torch.Tensor, ctx: StepContext) -> torch.Tensor:
        """``Q(i, x, .) = V(., x) + C(i, x, .) + CE(i, x, .)`` for the instances ``inst [B]``."""
        lay = self.layout
        idx, table = self.instance_index(self.C, ctx, inst)  # CE is laid out as C
        child_v = ctx.values["V"].gather(1, lay.table_children[table].clamp_min(0))
        ok = lay.table_child_valid[table]
        return child_v + self.C.read(idx, ok) + self.CE.read(idx, ok)

    # ------------------------------------------------------------------ updates
    def update(self, batch, ctx: StepContext, step: int) -> None:
        """Algorithm 1's updates for every finished child and primitive step in ``batch``."""
        level, prim = batch[LEVEL], batch[PRIMITIVE]
        alpha = self.alpha(step)
        lay = self.layout
        inst = level["inst"]
        learner = batch["learner"][:, None].expand_as(inst)
        table = lay.inst_table[inst.clamp_min(0)]
        terminal = level["terminal"]
        valid = level["valid"] & (level["child_done"] | terminal)
        t = self.time_of(batch)
        v_next = ctx.values["V"].gather(1, table)
        ce_next = ctx.values["CE"].gather(1, table)
        parent = level["parent_inst"]
        outer = ctx.values["W"].gather(1, lay.inst_table[parent.clamp_min(0)])
        outer = torch.where(parent >= 0, outer, torch.zeros_like(outer))
        c_target, ce_target = three_part_targets(self.discount(t), terminal, v_next, ce_next, outer)
        idx = self.C.index(learner, table, level["state"], level["child"])
        self.record_td(learner, level["node"], c_target - self.C.read(idx, valid), valid)
        flat_idx, flat_valid = idx.reshape(-1), valid.reshape(-1)
        self.C.update(flat_idx, c_target.reshape(-1), alpha, flat_valid)  # line 17
        self.CE.update(flat_idx, ce_target.reshape(-1), alpha, flat_valid)  # lines 19 / 21
        if self.all_states and "visited_state" in level.keys():
            # line 16: every x in ChildSeq, with the time left after it
            late = level["visited_valid"] & (level["visited_steps"] > 0) & valid[..., None]
            left = t[..., None] - self.time_of(batch, "visited_steps", "visited_time")
            c_k, ce_k = three_part_targets(
                self.discount(left),
                terminal[..., None],
                v_next[..., None],
                ce_next[..., None],
                outer[..., None],
            )
            vidx = self.C.index(
                learner[..., None],
                table[..., None],
                level["visited_state"],
                level["child"][..., None],
            ).reshape(-1)
            self.C.update(vidx, c_k.reshape(-1), alpha, late.reshape(-1))
            self.CE.update(vidx, ce_k.reshape(-1), alpha, late.reshape(-1))
        prim_table = lay.inst_table[prim["inst"].clamp_min(0)]
        pidx = self.V.index(batch["learner"], prim_table, prim["state"], 0)
        self.V.update(pidx, self.primitive_target(batch), alpha, prim["valid"])  # line 5
