"""SMDP Q-learning at every subtask, and flat Q-learning as its one-level special case.

Each non-primitive ``i`` keeps ``Q(i, s, a)`` over its children and treats them as temporally
extended actions (Sutton et al. 1999; Dietterich's HSMQ). After child ``a`` ran from ``s`` to
``s'`` in time ``tau`` with discounted reward ``R``::

    Q(i, s, a) <- (1-alpha) Q(i, s, a) + alpha [R + gamma^tau max_a' Q(i, s', a')]

(internal rewards of ``i`` added to ``R``; a terminal ``s'`` contributes only its pseudo reward).
On a graph whose root has the primitive actions as children and the full state as its
abstraction this is Watkins' Q-learning.
"""

from __future__ import annotations

import torch

from hrl_torch.common.ops import discount, lookup
from hrl_torch.execution.transitions import LEVEL
from hrl_torch.hierarchy.graph import StepContext
from hrl_torch.learners.base import TabularLearner, finished


class SMDPQLearner(TabularLearner):
    """SMDP Q-learning for a population of ``P`` learners (see the module docstring).

    Args:
        graph: the task graph (a flat graph gives Q-learning).
        n_learners: population size ``P``.
        alpha: step size (number or schedule).
        gamma: discount factor.
        per_instance: tables per Task-Stack context rather than per subtask.
        init: initial action values.
    """

    uses = frozenset()
    value_keys = ("V", "Q")

    def __init__(
        self, graph, n_learners, alpha=0.5, gamma=1.0, per_instance=False, init: float = 0.0
    ) -> None:
        super().__init__(graph, n_learners, alpha, gamma, per_instance)
        self.Q = self.completion_bank(init)
        self.attach_heads(Q=self.Q)

    def evaluate(self, ctx: StepContext) -> None:
        """``Q(i, s, .)`` rows and ``V(i, s) = max_a Q(i, s, a)`` for every non-primitive table."""
        blocked, dead, (q,) = self.composite_rows(ctx, self.Q)
        best = q.masked_fill(blocked, -torch.inf).amax(-1)
        value = torch.zeros(q.shape[0], self.layout.n_tables, device=q.device)
        ctx.values["V"] = value.index_copy_(1, self.plan.order, best.masked_fill(dead, 0.0))
        ctx.values["Q"] = q

    def update(self, batch, step: int) -> None:
        """One SMDP Q-learning step for every finished child in ``batch``."""
        level = batch[LEVEL]
        learner = batch["learner"][:, None]
        table = lookup(self.layout.inst_table, level["inst"].clamp_min(0))
        terminal = level["terminal"]
        valid = finished(level)
        factor = discount(self.gamma, level["duration"])
        continuation = torch.where(
            terminal, level["pseudo_reward"], batch["values", "V"].gather(1, table)
        )
        target = level["discounted_reward"] + level["internal_reward"] + factor * continuation
        idx = self.Q.index(learner, table, level["state"], level["child"])
        self.record_td(learner, level["node"], target - self.Q.read(idx, valid), valid)
        self.Q.update(idx.view(-1), target.view(-1), self.alpha(step), valid.view(-1))
