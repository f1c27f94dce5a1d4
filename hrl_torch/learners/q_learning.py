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

from hrl_torch.executor import LEVEL
from hrl_torch.graph import StepContext
from hrl_torch.learners.base import TabularLearner
from hrl_torch.ops import columns, discount, lookup


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

    def __init__(
        self, graph, n_learners, alpha=0.5, gamma=1.0, per_instance=False, init: float = 0.0
    ) -> None:
        super().__init__(graph, n_learners, alpha, gamma, per_instance)
        self.Q = self.completion_bank(init)
        self.attach_heads(Q=self.Q)
        self.composite = self.layout.composite_ids()

    def evaluate(self, ctx: StepContext) -> None:
        """``max_a Q(i, s, a)`` over available children for every non-primitive table node."""
        lay = self.layout
        ids = self.composite
        nodes = lookup(lay.table_node, ids)
        available = columns(ctx.available, nodes)
        q = self.table_rows(self.Q, ctx, ids, available)
        best = torch.where(available, q, -torch.inf).amax(-1)
        dead = columns(ctx.blocked, nodes) | ~available.any(-1)
        value = torch.zeros(q.shape[0], lay.n_tables, device=q.device)
        value.index_copy_(1, ids, torch.where(dead, 0.0, best))
        ctx.values["V"] = value

    def action_values(self, inst: torch.Tensor, ctx: StepContext) -> torch.Tensor:
        """``Q(i, s, .)`` for the instances ``inst [B]``."""
        return self.instance_rows(self.Q, ctx, inst)[0]

    def update(self, batch, ctx: StepContext, step: int) -> None:
        """One SMDP Q-learning step for every finished child in ``batch``."""
        level = batch[LEVEL]
        lay = self.layout
        learner = batch["learner"][:, None].expand_as(level["inst"])
        table = lookup(lay.inst_table, level["inst"].clamp_min(0))
        terminal = level["terminal"]
        valid = level["valid"] & (level["child_done"] | terminal)
        factor = discount(self.gamma, level["duration"])
        continuation = torch.where(
            terminal, level["pseudo_reward"], ctx.values["V"].gather(1, table)
        )
        target = level["discounted_reward"] + level["internal_reward"] + factor * continuation
        idx = self.Q.index(learner, table, level["state"], level["child"])
        self.record_td(learner, level["node"], target - self.Q.read(idx, valid), valid)
        self.Q.update(idx.reshape(-1), target.reshape(-1), self.alpha(step), valid.reshape(-1))
