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

from hrl_torch.common.ops import argmax_last, discount, entries, take_flat
from hrl_torch.execution.transitions import LEVEL, PRIMITIVE
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners.base import TabularLearner, finished
from hrl_torch.modules.schedules import Schedule


class MaxQLearner(TabularLearner):
    """MAXQ-Q for a population of ``P`` learners.

    Reads no optional transition keys (``uses``).

    Args:
        graph: the task graph.
        n_learners: population size ``P``.
        alpha: step size (number or schedule).
        gamma: discount factor.
        all_states: also update ``C`` (and ``C~``) for every state visited during the child
            (Algorithm 4, lines 15-17 and 25-27; needs the executor's ``record_visited``).
            Refused for nodes whose internal rewards read their invocation's memory.
        per_instance: tables per Task-Stack context rather than per subtask.
        init: initial completion values (see docs/design.md on initialisation and loops).
        init_internal: initial internal completions ``C~`` of the subtasks with internal
            rewards of their own (``graph.internal_nodes``; default: ``init``), e.g.
            pessimistic ones for subtasks whose internal rewards are step costs. Every other
            node's ``C~`` starts at ``init``: a node's initial values come from its own rewards,
            so a subtask's step-cost pessimism never reaches a parent without step costs
            (docs/defaults.md, "The discount trap").
        init_nodes: initial completions (``C`` and ``C~``) of the named subtasks instead,
            e.g. optimistic ones at a cooperative root so that every joint choice is tried.
    """

    uses = frozenset()
    value_keys = ("V", "V_int", "Q")
    targets_at_finished_levels = True  # (``update``: every read masked by ``finished``)

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
        init_nodes: dict[str, float] | None = None,
    ) -> None:
        super().__init__(graph, n_learners, alpha, gamma, per_instance)
        self.all_states = all_states
        remembering = [
            graph.nodes[k].name for k in graph.internal_nodes if graph.nodes[k].memory_size
        ]
        if all_states and remembering:
            raise GraphError(
                f"all-states updating: the internal rewards of {remembering} depend on where "
                "their invocation started, which a visited state does not hold"
            )
        self.internal = bool(graph.internal_nodes)
        self.C = self.completion_bank(init)
        c_int_init = init if init_internal is None else init_internal
        self.V = self.primitive_bank()
        if self.internal:
            self.C_int = self.completion_bank(c_int_init)
            self.share_store(C=self.C, V=self.V, C_int=self.C_int)
            self._start_like_external(graph, init)
        else:
            self.C_int = self.C
            self.share_store(C=self.C, V=self.V)
        internal = {"C_int": self.C_int} if self.internal else {}
        self.attach_heads(C=self.C, **internal, V=self.V)
        for name, value in (init_nodes or {}).items():  # initial completions of some nodes
            if name not in graph.index or graph.node(name).is_primitive:
                raise GraphError(f"init_nodes: {name!r} is not a subtask of the graph")
            for key in ("C", "C_int") if self.internal else ("C",):
                self.heads[name][key].fill_(float(value))

    def _start_like_external(self, graph: TaskGraph, init) -> None:
        """``C~`` of the tables whose node has no internal rewards starts at ``init`` (``C``'s).

        Their internal target is the external one (no pseudo or shaping reward of theirs), so
        a start of ``init_internal`` there would be another node's step cost (the four-AGV
        root's -49.96 under ``gamma^tau``: docs/defaults.md, "The discount trap").
        """
        own = set(graph.internal_nodes)
        lay = self.layout
        start = torch.as_tensor(init, dtype=self.C_int.store.dtype).reshape(-1, 1, 1)
        for t, node in enumerate(lay.table_node.tolist()):
            if node not in own and not graph.nodes[node].is_primitive:
                block = self.C_int.block(t)
                block.copy_(start.expand_as(block))

    # ------------------------------------------------------------------ values
    def evaluate(self, ctx: StepContext) -> None:
        """Bottom-up ``V(i, s)`` (external), ``max_a Q~(i, s, a)`` and the rows ``Q~(i, s, .)``.

        ``ctx.values``: ``V``, ``V_int`` ``[B, T]``; ``Q`` ``[B, Tc, A]`` (plan order).
        """
        banks = (self.C, self.C_int) if self.internal else (self.C,)
        # (penalty: -inf for unavailable children, 0 elsewhere; q + penalty masks them)
        penalty, dead, rows = self.composite_rows(ctx, *banks, penalty=True)
        bottom_up_values(self, ctx, penalty, dead, rows)

    # ------------------------------------------------------------------ updates
    def targets(self, level, terminal, v_next, v_next_int):
        """External and internal completion targets ``[B, D]`` (Dietterich's Table 4).

        ``gamma^N V(i, s')`` and ``R~ + gamma^N [R~_i(s') at a terminal s', else V~(i, s')]``
        (a terminal ``s'`` has no continuation).
        """
        external = v_next.masked_fill(terminal, 0.0)
        factor = None if self.gamma == 1.0 else discount(self.gamma, level["duration"])
        if factor is not None:
            external = factor * external
        if not self.internal:  # every internal reward is 0: the same target
            return external, external
        internal = torch.where(terminal, level["pseudo_reward"], v_next_int)
        if factor is not None:
            internal = factor * internal
        return external, level["internal_reward"] + internal

    def update(self, batch, step: int) -> None:
        """Dietterich's MAXQ-Q updates for every finished child and primitive in ``batch``.

        One update of the shared store: ``C`` (and ``C~``) of every level whose child finished,
        ``V(a, s) <- (1-alpha) V + alpha r`` of the primitive on its level (``ran``).
        """
        fields = entries(batch)
        level, values = entries(fields[LEVEL]), entries(fields["values"])
        alpha = self.alpha(step)
        table = self.level_table(level)
        terminal, ran = level["terminal"], level["ran"]
        valid = finished(level)
        v_next = values["V"].gather(1, table)
        v_next_int = values["V_int"].gather(1, table) if self.internal else v_next
        target, target_int = self.targets(level, terminal, v_next, v_next_int)
        target = torch.where(ran, entries(fields[PRIMITIVE])["reward"][:, None], target)
        index = self.entry_index(fields["learner"], level, table)
        mask = valid | ran
        if self.internal:  # C~ sits at a fixed distance from C in every learner's block
            index = torch.cat([index, index + (self.C_int.base - self.C.base)], 1)
            target = torch.cat([target, target_int], 1)
            mask = torch.cat([mask, valid], 1)
        distinct = self.rows_distinct(fields["learner"])
        old = self.tables.update(index, target, alpha, mask, distinct)
        if self.internal:
            old = old[:, valid.shape[1] :]
        learner = self.plan.learner_base(fields["learner"], 1, 2)  # [B, 1]
        self.record_td(learner, level["node"], target_int - old, valid)
        if self.all_states and "visited_state" in level.keys():
            self._update_visited(batch, table, terminal, valid, v_next, v_next_int, alpha)

    def _update_visited(self, batch, table, terminal, valid, v_next, v_next_int, alpha) -> None:
        """All-states updating (Algorithm 4, lines 15-17 and 25-27).

        Every state ``s_k`` the child passed, ``t_k`` into it, gets the target from ``s_k``::

            C(i, s_k, a)  <- (1-alpha) C  + alpha g^(N - t_k) [C(i, s', a*) + V(a*, s')]
            C~(i, s_k, a) <- (1-alpha) C~ + alpha [R~_k + g^(N - t_k) (R~_i(s') or V~(i, s'))]

        with ``R~_k`` the shaping of ``i`` from ``s_k`` on, discounted to ``s_k``: the child's
        whole shaping less what was collected before ``s_k``, over ``gamma^t_k``.
        """
        level = batch[LEVEL]
        remaining = level["duration"][..., None] - level["visited_time"]
        factor = discount(self.gamma, remaining)
        external = factor * v_next[..., None].masked_fill(terminal[..., None], 0.0)
        internal = factor * torch.where(
            terminal[..., None], level["pseudo_reward"][..., None], v_next_int[..., None]
        )
        if "visited_internal" in level.keys():  # the shaping from s_k on
            shaping = level["internal_reward"][..., None] - level["visited_internal"]
            internal = internal + shaping / discount(self.gamma, level["visited_time"])
        targets = [(self.C, external)]
        if self.internal:  # (C~ sits at a fixed distance from C, as in ``update``)
            targets.append((self.C_int, internal))
        self.update_visited(batch, table, valid, alpha, targets)


def bottom_up_values(learner, ctx, penalty, dead, rows) -> None:
    """``V``, ``V_int`` ``[B, T]`` and ``Q`` ``[B, Tc, A]`` into ``ctx.values``, bottom-up.

    ``V(i, s) = max_a [V(a, s) + C(i, s, a)]`` (the MAXQ decomposition); with internal
    completions the greedy child of ``Q~`` picks both (Eq. 3.6). ``rows``: the completion rows
    ``C`` (and ``C~``) of every composite table at its state (a table's or a network's).
    """
    value = learner.primitive_values(ctx, learner.V)
    value_int = value.clone() if learner.internal else value
    q_rows = []
    for ids, kids, unavailable, gone, c, *c_int in learner.groups(penalty, dead, *rows):
        child_v = take_flat(value, kids)
        q_ext = child_v + c
        if learner.internal:  # V(i, s) = Q(i, s, a*) with a* greedy for Q~ (Eq. 3.6)
            q_int = child_v + c_int[0]
            best = argmax_last(q_int + unavailable, keepdim=True)
            v_ext = q_ext.gather(-1, best).squeeze(-1)
            v_int = q_int.gather(-1, best).squeeze(-1)
            value_int.index_copy_(1, ids, v_int.masked_fill(gone, 0.0))
        else:
            q_int = q_ext
            v_ext = (q_ext + unavailable).amax(-1)
        value.index_copy_(1, ids, v_ext.masked_fill(gone, 0.0))
        q_rows.append(q_int)
    ctx.values["V"] = value
    ctx.values["V_int"] = value_int
    ctx.values["Q"] = torch.cat(q_rows, 1)
