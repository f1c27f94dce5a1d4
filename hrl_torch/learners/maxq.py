"""MAXQ-Q (Dietterich 2000): the two-part decomposition with internal and external completions.

Values (Equations 3.5 and 3.6), for a non-primitive ``i`` and child ``a``::

    Q(i, s, a) = V(a, s) + C(i, s, a)           external, propagated to the parents
    Q~(i, s, a) = V(a, s) + C~(i, s, a)         internal, chooses the child of ``i``
    V(i, s) = Q(i, s, a*),  a* = argmax_a Q~(i, s, a)      (V(a, s) learned for primitives)

Updates after child ``a`` of ``i`` ran from ``s`` to ``s'`` in ``N`` steps (Dietterich's
Table 4)::

    C~(i, s, a) <- (1-alpha) C~ + alpha * gamma^N [R~_i(s') + C~(i, s', a*) + V(a*, s')]
    C(i, s, a)  <- (1-alpha) C  + alpha * gamma^N [C(i, s', a*) + V(a*, s')]
    V(a, s)     <- (1-alpha) V  + alpha * r                      (primitive a)

with ``a* = argmax_a' [C~(i, s', a') + V(a', s')]``; a terminal ``s'`` has no continuation, only
the pseudo reward ``R~_i(s')`` in the internal target. Shaping rewards of ``i`` collected while
``a`` ran enter the internal target only (Section 3.1).
"""

from __future__ import annotations

import torch

from hrl_torch.executor import LEVEL, PRIMITIVE
from hrl_torch.exploration import Schedule, masked_argmax
from hrl_torch.graph import GraphError, StepContext, TaskGraph
from hrl_torch.learners.base import TabularLearner
from hrl_torch.ops import columns, discount, lookup


class MaxQLearner(TabularLearner):
    """MAXQ-Q for a population of ``P`` learners.

    Args:
        graph: the task graph.
        n_learners: population size ``P``.
        alpha: step size (number or schedule).
        gamma: discount factor.
        all_states: also update ``C`` for every state visited during the child (needs the
            executor's ``record_visited``).
        per_instance: tables per Task-Stack context rather than per subtask.
        init: initial completion values (see docs/design.md on initialisation and loops).
        init_internal: initial internal completions ``C~`` (default: ``init``), e.g.
            pessimistic ones for subtasks whose internal rewards are step costs.
    """

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        alpha: float | Schedule = 0.5,
        gamma: float = 1.0,
        all_states: bool = False,
        per_instance: bool = False,
        init: float = 0.0,
        init_internal: float | None = None,
    ) -> None:
        super().__init__(graph, n_learners, alpha, gamma, per_instance)
        self.all_states = all_states
        if all_states and graph.shaping_nodes:
            raise GraphError("all-states updating with per-step shaping rewards is not supported")
        self.internal = bool(graph.internal_nodes)
        self.C = self.completion_bank(init)
        c_int_init = init if init_internal is None else init_internal
        self.C_int = self.completion_bank(c_int_init) if self.internal else self.C
        self.V = self.primitive_bank()
        internal = {"C_int": self.C_int} if self.internal else {}
        self.attach_heads(C=self.C, **internal, V=self.V)

    # ------------------------------------------------------------------ values
    def evaluate(self, ctx: StepContext) -> None:
        """Bottom-up ``V(i, s)`` (external), ``max_a Q~(i, s, a)`` and the rows ``Q~(i, s, .)``.

        ``ctx.values``: ``V``, ``V_int`` ``[B, T]``; ``Q`` ``[B, Tc, A]`` (plan order).
        """
        banks = (self.C, self.C_int) if self.internal else (self.C,)
        available, dead, rows = self.composite_rows(ctx, *banks)
        value = self.primitive_values(ctx, self.V)
        value_int = value.clone() if self.internal else value
        q_rows = []
        for part, ids in self.groups():
            child_v = columns(value, self.plan.child_table[part])
            q_ext = child_v + rows[0][:, part]
            q_int = child_v + rows[-1][:, part] if self.internal else q_ext
            ok, gone = available[:, part], dead[:, part]
            if self.internal:  # V(i, s) = Q(i, s, a*) with a* greedy for Q~ (Eq. 3.6)
                best = masked_argmax(q_int, ok).unsqueeze(-1)
                v_ext = q_ext.gather(-1, best).squeeze(-1)
                v_int = q_int.gather(-1, best).squeeze(-1)
                value_int.index_copy_(1, ids, v_int.masked_fill(gone, 0.0))
            else:
                v_ext = torch.where(ok, q_ext, -torch.inf).amax(-1)
            value.index_copy_(1, ids, v_ext.masked_fill(gone, 0.0))
            q_rows.append(q_int)
        ctx.values["V"] = value
        ctx.values["V_int"] = value_int
        ctx.values["Q"] = torch.cat(q_rows, 1)

    # ------------------------------------------------------------------ updates
    @staticmethod
    def targets(discount, internal, terminal, pseudo, v_next, v_next_int):
        """External and internal completion targets (all arguments broadcast together)."""
        external = discount * v_next.masked_fill(terminal, 0.0)
        internal = internal + discount * torch.where(terminal, pseudo, v_next_int)
        return external, internal

    def update(self, batch, step: int) -> None:
        """Dietterich's MAXQ-Q updates for every finished child and primitive in ``batch``."""
        level, prim, values = batch[LEVEL], batch[PRIMITIVE], batch["values"]
        alpha = self.alpha(step)
        learner = batch["learner"][:, None]
        table = lookup(self.layout.inst_table, level["inst"].clamp_min(0))
        terminal = level["terminal"]
        valid = level["valid"] & (level["child_done"] | terminal)
        v_next = values["V"].gather(1, table)
        v_next_int = values["V_int"].gather(1, table) if self.internal else v_next
        target, target_int = self.targets(
            discount(self.gamma, level["duration"]),
            level["internal_reward"],
            terminal,
            level["pseudo_reward"],
            v_next,
            v_next_int,
        )
        idx = self.C.index(learner, table, level["state"], level["child"])
        self.record_td(learner, level["node"], target_int - self.C_int.read(idx, valid), valid)
        self.C.update(idx.view(-1), target.view(-1), alpha, valid.view(-1))
        if self.internal:
            self.C_int.update(idx.view(-1), target_int.view(-1), alpha, valid.view(-1))
        if self.all_states and "visited_state" in level.keys():
            # every state s_k the child passed through gets the target discounted from s_k
            late = level["visited_valid"] & (level["visited_steps"] > 0) & valid[..., None]
            remaining = level["duration"][..., None] - level["visited_time"]
            ext, internal = self.targets(
                discount(self.gamma, remaining),
                torch.zeros_like(remaining),
                terminal[..., None],
                level["pseudo_reward"][..., None],
                v_next[..., None],
                v_next_int[..., None],
            )
            vidx = self.C.index(
                learner[..., None],
                table[..., None],
                level["visited_state"],
                level["child"][..., None],
            )
            self.C.update(vidx.reshape(-1), ext.reshape(-1), alpha, late.reshape(-1))
            if self.internal:
                self.C_int.update(vidx.reshape(-1), internal.reshape(-1), alpha, late.reshape(-1))

        pidx = self.table_index(self.V, batch["learner"], prim["inst"], prim["state"], 0)
        self.V.update(pidx, prim["reward"], alpha, prim["valid"])
