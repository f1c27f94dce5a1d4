"""Hierarchical hybrid learning (Section 5.3): value-based and policy-gradient nodes in one graph.

``HybridLearner`` routes every node of a task graph to one of two learners: a value learner
(e.g. ``QLambdaLearner`` at the top, choosing among subtasks with an exploration strategy) and
an ``HPGRLLearner`` (parameterised policies below, sampling their choices, possibly continuous
actions). Both see every transition batch and learn only from their own nodes' transitions.
``HybridPolicy`` makes the executor's choices: per env row, the value learner's action values
with exploration where the node is value-based, the PG policy where it is not.

Section 5.3's exploration schedule is ``hrl_torch.modules.exploration.TriggeredEpsilon``: epsilon
stays at 0.1 until the low-level subtasks perform well enough (a domain's
``hrl_torch.learners.progress.Monitor`` decides), then it is divided by 1.01 every 50 episodes, per
learner of the population. (Both, and ``EpisodeBins``, are re-exported here.)
"""

from __future__ import annotations

import torch
from torch import nn

from hrl_torch.common.rng import LevelDraws
from hrl_torch.execution.transitions import Choice
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners.base import Learner
from hrl_torch.learners.pg import HPGRLLearner
from hrl_torch.learners.progress import EpisodeBins, Monitor  # noqa: F401  (re-exported)
from hrl_torch.modules.exploration import (  # noqa: F401  (TriggeredEpsilon: re-exported)
    Exploration,
    Greedy,
    TriggeredEpsilon,
    uniform_choice,
)


class HybridLearner(Learner):
    """Value-based nodes and policy-gradient nodes of one graph, each with its own learner.

    Args:
        graph: the task graph.
        n_learners: population size ``P``.
        value: learner of the value nodes (provides ``action_values``).
        pg: learner of the PG nodes.
        epsilon: Section 5.3's schedule for the value nodes' epsilon-greedy choices during
            training (``None``: the trainer's exploration is used as given).
        monitor: domain progress (drives ``epsilon``; its metrics are the domain's).
    """

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        value: Learner,
        pg: HPGRLLearner,
        epsilon: TriggeredEpsilon | None = None,
        monitor: nn.Module | None = None,
    ) -> None:
        super().__init__(graph, n_learners)
        self.value_keys = (*value.value_keys, *pg.value_keys)
        pg_nodes = set((pg.node_group >= 0).nonzero().flatten().tolist())
        value_nodes = value.value_nodes()
        if value_nodes is None:  # a value learner of every node: those that are not PG's
            value_nodes = set(graph.subtasks()) - pg_nodes
        both = pg_nodes & value_nodes
        if both:
            raise GraphError(f"nodes {[graph.names[k] for k in both]} have two learners")
        missing = set(graph.subtasks()) - pg_nodes - value_nodes
        if missing:
            raise GraphError(f"nodes {[graph.names[k] for k in missing]} have no learner")
        self.value, self.pg = value, pg
        self.epsilon = epsilon
        self.monitor = monitor
        self.gamma = value.gamma

    def log_scalars(self, step: int) -> dict[str, list[float]]:
        """The PG nodes' scalars at a log (``HPGRLLearner.log_scalars``)."""
        return self.pg.log_scalars(step)

    def evaluate(self, ctx: StepContext) -> None:
        """Both learners' per-step values."""
        self.value.evaluate(ctx)
        self.pg.evaluate(ctx)

    def action_values(self, inst: torch.Tensor, ctx: StepContext, rows=None) -> torch.Tensor:
        """The value learner's action values (of the batch rows ``rows`` when given)."""
        return self.value.action_values(inst, ctx, rows)

    @property
    def score_width(self) -> int:
        """The PG nodes' likelihood-ratio width (the executor keeps the terms per level)."""
        return self.pg.score_width

    def update(self, batch, step: int) -> None:
        """Each learner learns from its nodes' transitions; the monitor sees the batch."""
        self.value.update(batch, step)
        self.pg.update(batch, step)
        for part in (self.value, self.pg):
            self.td_abs += part.td_abs
            self.td_count += part.td_count
            part.td_abs.zero_()
            part.td_count.zero_()
        if self.monitor is not None:
            ended, trigger = self.monitor.observe(batch)
            if self.epsilon is not None:
                self.epsilon.observe(ended, trigger)

    def make_policy(self, exploration: Exploration, rng, evaluate: bool = False) -> HybridPolicy:
        """Training policy, or with ``evaluate`` the greedy one (PG nodes on their modes)."""
        return HybridPolicy(self, exploration, rng, evaluate)


class HybridPolicy:
    """Executor policy of a hybrid graph: exploration over action values, or PG sampling.

    Each push reads one block of ``A + 1 + W`` uniforms per row: ``A + 1`` for the value nodes'
    exploration, ``W`` (the PG learner's ``n_uniforms``, 3 unless a head needs more) for the
    PG policies.

    Args:
        learner: the hybrid learner.
        exploration: the value nodes' strategy (replaced by epsilon-greedy with the learner's
            ``TriggeredEpsilon`` in training when it has one).
        rng: random numbers for the rows.
        evaluate: every node greedy (value nodes on their best child, PG nodes on their
            modes), nothing recorded.
    """

    def __init__(
        self, learner: HybridLearner, exploration: Exploration, rng, evaluate: bool = False
    ) -> None:
        self.learner = learner
        self.exploration = exploration
        self.greedy = evaluate
        self.rng = rng
        width = learner.graph.max_children + 1 + learner.pg.n_uniforms
        self.draws = LevelDraws(rng, learner.graph, width)

    def new_step(self) -> None:
        """Take this step's draw (``A + 4`` uniforms per level, read when asked)."""
        self.draws.new_step()

    def select(self, inst, ctx: StepContext, available, step: int, push: int) -> Choice:
        """The choices of the ``push``-th push of the step."""
        return self._choose(inst, ctx, available, step, self.draws.level(push))

    def select_rows(self, inst, ctx: StepContext, available, step: int, push: int, rows):
        """``select`` for the batch rows ``rows [R]`` only (their numbers alone are drawn)."""
        return self._choose(inst, ctx, available, step, self.draws.level_rows(push, rows), rows)

    def _choose(self, inst, ctx, available, step, u, rows=None) -> Choice:
        """The choices of instances ``inst`` (at batch rows ``rows``; all rows if ``None``)."""
        lrn = self.learner
        a = available.shape[1]
        node = lrn.graph.inst_node[inst]
        pg_row = lrn.pg.node_group[node] >= 0
        out = lrn.pg.select(inst, ctx, available, u[:, a + 1 :], self.greedy, rows=rows)
        # the value nodes' choices for every row (static shapes: no read of which rows are
        # PG's); on the CPU they are skipped when every row is (a read that syncs nothing)
        if not lrn.pg.static(pg_row.device) and bool(pg_row.all()):
            return out
        q = lrn.value.action_values(inst, ctx, rows)
        best, _ = Greedy().select(q, available, u, step)
        if self.greedy:
            v_choice, v_flag = best, torch.ones_like(pg_row)
        elif lrn.epsilon is not None:
            learner = ctx.learner if rows is None else ctx.learner[rows]
            explore = u[:, a] < lrn.epsilon.values()[learner]
            v_choice = torch.where(explore, uniform_choice(available, u[:, :a]), best)
            v_flag = v_choice == best
        else:
            v_choice, v_flag = self.exploration.select(q, available, u[:, : a + 1], step)
        out.child = torch.where(pg_row, out.child, v_choice)
        out.greedy = torch.where(pg_row, out.greedy, v_flag)
        return out
