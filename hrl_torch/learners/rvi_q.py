"""RVI Q-learning (Abounadi, Bertsekas and Borkar 2001): flat average-reward Q-learning.

On a flat graph (a root over the primitive actions, abstraction = the full state)::

    Q(s, a) <- (1-alpha) Q(s, a) + alpha [r - f(Q) t + max_a' Q(s', a')]

with ``t = 1`` in discrete time and the duration ``tau`` in continuous time (the SMDP version,
``continuous=True``). The reference function ``f`` (Abounadi et al.: ``f(e) = 1``,
``f(Q + c e) = f(Q) + c``) is the learner's gain estimate; two of their choices:

- ``f(Q) = max_a Q(s_ref, a)`` for a reference state ``s_ref`` (``reference_state``): it moves
  as fast as that state is visited, so pick a state the process visits often;
- ``f(Q) = sum_{s,a} Q(s, a) / (|S| |A|)``, the mean of the whole table (default). We keep the
  table's sum exactly (per learner, float64) from the change of every updated entry, so it
  costs nothing per step; but every update moves the mean by only ``alpha delta / (|S| |A|)``,
  so on a large table (the AGV's 6.7 million entries) ``f`` lags the gain for millions of
  steps and the visited values drift.

In continuous time the reference entry's own update multiplies it by ``1 - alpha (1 + t)``:
with ``t`` in seconds and actions of about 10 s the iteration diverges for any ``alpha`` above
about 0.18. ``time_unit`` sets the unit time is measured in (durations are divided by it, e.g.
the mean action duration), which keeps ``t`` near 1; ``gain`` is reported per original unit.
"""

from __future__ import annotations

import torch

from hrl_torch.common.ops import group_of_rows
from hrl_torch.execution.transitions import LEVEL
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners.base import TabularLearner
from hrl_torch.modules.schedules import Schedule


class RVIQLearner(TabularLearner):
    """RVI Q-learning on a flat graph for a population of ``P`` learners.

    Args:
        graph: a flat task graph (the root's children are all primitives).
        n_learners: population size ``P``.
        alpha: step size (number or schedule).
        continuous: SMDP (continuous-time) version: the reference is charged per unit of time.
        init: initial action values.
        reference_state: abstract state ``s_ref`` of ``f(Q) = max_a Q(s_ref, a)`` (``None``:
            the mean of the table).
        time_unit: durations are measured in this unit (continuous time).
    """

    value_keys = ("V", "Q")

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        alpha: float | Schedule = 0.1,
        continuous: bool = False,
        init: float = 0.0,
        reference_state: int | None = None,
        time_unit: float = 1.0,
    ) -> None:
        super().__init__(graph, n_learners, alpha, 1.0, per_instance=False)
        kids = graph.node_children[graph.root, : int(graph.node_n_children[graph.root])]
        if not bool(graph.node_is_primitive[kids].all()):
            raise GraphError("RVI Q-learning needs a flat graph: every child of the root primitive")
        self.continuous = continuous
        self.reference_state = reference_state
        self.time_unit = float(time_unit)
        self.Q = self.completion_bank(init)
        self.attach_heads(Q=self.Q)
        self.n_entries = self.Q.total
        self._root_width = int(graph.node_n_children[graph.root])  # (read once, on the CPU)
        if reference_state is not None:  # (made once, moved with the module: no host copy)
            self.register_buffer("reference_index", torch.tensor(reference_state), persistent=False)
        q_sum = torch.as_tensor(init, dtype=torch.float64) * self.n_entries  # (or per learner)
        self.register_buffer("q_sum", q_sum.expand(n_learners).clone())

    @property
    def gain(self) -> torch.Tensor:
        """The gain estimate per learner ``[P]``, per original unit of time."""
        return self.reference() / self.time_unit

    def reference(self) -> torch.Tensor:
        """``f(Q)`` per learner ``[P]`` (gain per ``time_unit``)."""
        if self.reference_state is None:
            return (self.q_sum / self.n_entries).float()
        root = self.layout.inst_table[0]
        width = self._root_width
        learners = torch.arange(self.n_learners, device=self.q_sum.device)
        idx = self.Q.row_index(learners, root, self.reference_index, width)
        return self.Q.read(idx).amax(-1)

    def evaluate(self, ctx: StepContext) -> None:
        """``Q(s, .)`` and ``max_a Q(s, a)`` at the root."""
        blocked, _, (q,) = self.composite_rows(ctx, self.Q)
        best = q.masked_fill(blocked, -torch.inf).amax(-1)
        value = torch.zeros(q.shape[0], self.layout.n_tables, device=q.device)
        value.index_copy_(1, self.plan.order, best.masked_fill(blocked.all(-1), 0.0))
        ctx.values["V"] = value
        ctx.values["Q"] = q

    def update(self, batch, step: int) -> None:
        """One RVI Q-learning step for every primitive step (level 0 of the flat stack)."""
        level = batch[LEVEL]
        lay = self.layout
        valid = level["valid"][:, 0] & (level["child_done"][:, 0] | level["terminal"][:, 0])
        learner = batch["learner"]
        table = lay.inst_table[level["inst"][:, 0].clamp_min(0)]
        if self.continuous:
            t = level["duration"][:, 0] / self.time_unit
        else:
            t = level["steps"][:, 0].float()
        v_next = batch["values", "V"].gather(1, table[:, None]).squeeze(1)
        v_next = torch.where(level["terminal"][:, 0], torch.zeros_like(v_next), v_next)
        target = level["reward"][:, 0] - self.reference()[learner] * t + v_next
        idx = self.Q.index(learner, table, level["state"][:, 0], level["child"][:, 0])
        old = self.Q.read(idx, valid)
        self.record_td(learner, level["node"][:, 0], target - old, valid)
        self.Q.update(idx, target, self.alpha(step), valid)
        # keep sum(Q) exact: every updated entry's change once, however many rows hit it
        change = self.Q.read(idx, valid) - old
        safe = torch.where(valid, idx, -1)
        group = group_of_rows(safe)  # (``unique``'s inverse with no host read)
        counts = torch.zeros_like(change).index_add_(0, group, torch.ones_like(change))
        self.q_sum.index_add_(0, learner, (change / counts.index_select(0, group)).double())
