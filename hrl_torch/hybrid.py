"""Hierarchical hybrid learning (Section 5.3): value-based and policy-gradient nodes in one graph.

``HybridLearner`` routes every node of a task graph to one of two learners: a value learner
(e.g. ``QLambdaLearner`` at the top, choosing among subtasks with an exploration strategy) and
an ``HPGRLLearner`` (parameterised policies below, sampling their choices, possibly continuous
actions). Both see every transition batch and learn only from their own nodes' transitions.
``HybridPolicy`` makes the executor's choices: per env row, the value learner's action values
with exploration where the node is value-based, the PG policy where it is not.

Section 5.3's exploration schedule is ``TriggeredEpsilon``: epsilon stays at 0.1 until the
low-level subtasks perform well enough (a domain ``Monitor`` decides), then it is divided by
1.01 every 50 episodes, per learner of the population.

``EpisodeBins`` keeps per-learner sums over consecutive blocks of events (e.g. "successes per
1000 episodes", "low-level successes per 1000 executions"): each finished event gets its index
within its learner, so blocks are exact however many envs a learner runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import torch
from torch import nn

from hrl_torch.executor import Choice
from hrl_torch.exploration import Exploration, Greedy, uniform_choice
from hrl_torch.graph import GraphError, StepContext, TaskGraph
from hrl_torch.learners.base import Learner
from hrl_torch.learners.pg import HPGRLLearner
from hrl_torch.rng import LevelDraws


class TriggeredEpsilon(nn.Module):
    """Per-learner epsilon: ``start`` until a trigger, then ``start / factor ** (n // every)``.

    ``n`` counts the learner's episodes since its trigger fired (Section 5.3: 0.1, 1.01, 50).

    Args:
        n_learners: population size ``P``.
        start: initial epsilon.
        factor: divisor per ``every`` episodes after the trigger.
        every: episodes per division.
    """

    def __init__(
        self, n_learners: int, start: float = 0.1, factor: float = 1.01, every: int = 50
    ) -> None:
        super().__init__()
        self.start, self.factor, self.every = float(start), float(factor), int(every)
        self.register_buffer("episodes", torch.zeros(n_learners, dtype=torch.long))
        self.register_buffer("fired_at", torch.full((n_learners,), -1, dtype=torch.long))

    def observe(self, episodes_ended: torch.Tensor, trigger: torch.Tensor) -> None:
        """Count finished episodes ``[P]``; learners whose ``trigger [P]`` holds start decaying."""
        self.episodes += episodes_ended.long()
        fire = trigger & (self.fired_at < 0)
        self.fired_at = torch.where(fire, self.episodes, self.fired_at)

    def values(self) -> torch.Tensor:
        """Epsilon per learner ``[P]``."""
        since = (self.episodes - self.fired_at).clamp_min(0) // self.every
        decay = self.factor ** since.double()
        eps = torch.where(
            self.fired_at >= 0, self.start / decay, torch.full_like(decay, self.start)
        )
        return eps.float()


class Monitor(Protocol):
    """Domain knowledge about a hybrid's progress, fed every transition batch."""

    def observe(self, batch) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(episodes ended per learner [P], epsilon trigger per learner [P] bool)``."""
        ...


class EpisodeBins(nn.Module):
    """Per-learner sums of event values over consecutive blocks of ``size`` events.

    Args:
        n_learners: population size ``P``.
        size: events per block (e.g. 1000 episodes).
        n_bins: blocks kept; later events go to an overflow block.
        fields: names of the summed values (``count`` is kept too).
    """

    def __init__(self, n_learners: int, size: int, n_bins: int, fields: Sequence[str]) -> None:
        super().__init__()
        self.size, self.n_bins, self.fields = int(size), int(n_bins), list(fields)
        self.register_buffer("events", torch.zeros(n_learners, dtype=torch.long))
        self.register_buffer("sums", torch.zeros(len(self.fields) + 1, n_learners, n_bins + 1))

    def add(self, ended: torch.Tensor, values: dict[str, torch.Tensor]) -> None:
        """Add the events of the rows where ``ended [B]`` (rows grouped by learner).

        ``values``: ``{field: [B]}``; an event of row ``b`` is numbered after the learner's
        earlier events and after the events of rows ``< b`` of the same learner.
        """
        p = self.events.shape[0]
        per = ended.view(p, -1).long()
        rank = per.cumsum(1) - 1 + self.events[:, None]
        block = (rank // self.size).clamp(0, self.n_bins)
        flat = (torch.arange(p, device=ended.device)[:, None] * (self.n_bins + 1) + block).view(-1)
        weight = ended.float()
        stacked = torch.stack([weight] + [values[f].float() * weight for f in self.fields])
        self.sums.view(len(self.fields) + 1, -1).index_add_(1, flat, stacked)
        self.events += per.sum(1)

    def completed(self) -> torch.Tensor:
        """Blocks completed per learner ``[P]``."""
        return (self.events // self.size).clamp_max(self.n_bins)

    def block_means(self) -> dict[str, torch.Tensor]:
        """``{field: [P, n_bins]}`` mean value per event of each block (NaN while empty)."""
        count = self.sums[0, :, : self.n_bins]
        return {
            f: torch.where(
                count > 0, self.sums[k + 1, :, : self.n_bins] / count.clamp_min(1), torch.nan
            )
            for k, f in enumerate(self.fields)
        }


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
        pg_nodes = set((pg.node_group >= 0).nonzero().flatten().tolist())
        value_nodes = (
            set(value.value_node.nonzero().flatten().tolist())
            if hasattr(value, "value_node")
            else set(graph.subtasks()) - pg_nodes
        )
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

    Each push reads one block of ``A + 4`` uniforms per row: ``A + 1`` for the value nodes'
    exploration, 3 for the PG policies.

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
        self.draws = LevelDraws(rng, learner.graph, learner.graph.max_children + 4)

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
        if not bool(pg_row.all()):
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
