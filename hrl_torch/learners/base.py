"""What every learner provides, and the policy that turns its values into choices.

A learner is an update rule over batches of SMDP transitions (see ``hrl_torch.executor``):

- ``evaluate(ctx)`` computes, once per step, whatever per-node values its choices and targets
  need at the current observations and stores them in ``ctx.values``;
- ``action_values(inst, ctx)`` returns the values ``[B, A]`` of the children of the instances
  ``inst [B]`` that exploration chooses from;
- ``update(batch, ctx, step)`` applies one batch of transitions whose ``s'`` is ``ctx.obs``.

Learners never step envs and never touch the Task-Stack.
"""

from __future__ import annotations

import torch
from torch import nn

from hrl_torch.executor import LEVEL, PRIMITIVE
from hrl_torch.exploration import Exploration, Schedule, as_schedule, uniforms_needed
from hrl_torch.graph import StepContext, TaskGraph
from hrl_torch.heads import attach_table_heads
from hrl_torch.ops import columns, lookup
from hrl_torch.rng import BatchRNG
from hrl_torch.tables import TableBank, TableLayout
from hrl_torch.validate import check_fraction, check_step_size


class Learner(nn.Module):
    """Base class: a population of ``P`` independent learners over one task graph."""

    gamma: float = 1.0

    def __init__(self, graph: TaskGraph, n_learners: int) -> None:
        super().__init__()
        self.graph = graph
        self.n_learners = n_learners
        # |TD error| sums and counts per learner and node since the last log (saved: a resumed
        # run logs what an uninterrupted one would)
        self.register_buffer("td_abs", torch.zeros(n_learners, graph.n_nodes))
        self.register_buffer("td_count", torch.zeros(n_learners, graph.n_nodes))

    def evaluate(self, ctx: StepContext) -> None:
        """Fill ``ctx.values`` for the observations of ``ctx``."""

    def action_values(self, inst: torch.Tensor, ctx: StepContext) -> torch.Tensor:
        """Values ``[B, A]`` of the children of ``inst [B]`` (padding slots are ignored)."""
        raise NotImplementedError

    def update(self, batch, ctx: StepContext, step: int) -> None:
        """Learn from one batch of transitions ending in ``ctx.obs``."""
        raise NotImplementedError

    def record_td(
        self, learner: torch.Tensor, node: torch.Tensor, error: torch.Tensor, mask: torch.Tensor
    ) -> None:
        """Accumulate ``|error|`` per (learner, node) where ``mask`` (all shapes equal)."""
        idx = (learner * self.graph.n_nodes + node).reshape(-1)
        m = mask.reshape(-1).float()
        self.td_abs.view(-1).index_add_(0, idx, error.abs().reshape(-1).nan_to_num() * m)
        self.td_count.view(-1).index_add_(0, idx, m)


class TabularLearner(Learner):
    """Shared machinery of the tabular value learners: layout, banks and the step size.

    Args:
        graph: the task graph.
        n_learners: population size ``P``.
        alpha: step size (number or schedule over env steps).
        gamma: discount factor (1 for undiscounted episodic tasks).
        per_instance: tables per Task-Stack context instead of per subtask.
    """

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        alpha: float | Schedule = 0.5,
        gamma: float = 1.0,
        per_instance: bool = False,
    ) -> None:
        super().__init__(graph, n_learners)
        check_step_size(self, "alpha", alpha)
        check_fraction(self, "gamma", gamma)
        self.alpha = as_schedule(alpha)
        self.gamma = float(gamma)
        self.layout = TableLayout(graph, per_instance)
        self.continuous = False  # continuous-time learners measure time by durations

    def completion_bank(self, init: float = 0.0) -> TableBank:
        """A ``[n_states, n_children]`` table for every non-primitive table node."""
        lay = self.layout
        n_states = torch.where(lay.table_is_primitive, 0, lay.table_n_states)
        return TableBank(self.n_learners, n_states, lay.table_n_children.clamp_min(1), init)

    def primitive_bank(self, init: float = 0.0) -> TableBank:
        """A ``[n_states, 1]`` value table for every primitive table node."""
        lay = self.layout
        n_states = torch.where(lay.table_is_primitive, lay.table_n_states, 0)
        return TableBank(self.n_learners, n_states, torch.ones_like(n_states), init)

    def table_states(self, ctx: StepContext, tables: torch.Tensor) -> torch.Tensor:
        """Abstract states ``[B, n]`` of the table nodes ``tables [n]``."""
        return columns(ctx.abstract, lookup(self.layout.table_node, tables))

    def table_rows(
        self, bank: TableBank, ctx: StepContext, tables: torch.Tensor, available: torch.Tensor
    ) -> torch.Tensor:
        """Rows ``[B, n, A]`` of ``bank`` for tables ``[n]`` at ``ctx``; unavailable read 0."""
        idx = bank.row_index(
            ctx.learner[:, None],
            tables[None, :],
            self.table_states(ctx, tables),
            self.layout.max_children,
        )
        return bank.read(idx, available)

    def instance_index(
        self, bank: TableBank, ctx: StepContext, inst: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Row index ``[B, A]`` into ``bank`` for the instances ``inst [B]``, and their tables.

        Banks built alike (``completion_bank``) share the index.
        """
        lay = self.layout
        table = lookup(lay.inst_table, inst.clamp_min(0))
        state = ctx.abstract.gather(1, lookup(lay.table_node, table)[:, None]).squeeze(1)
        return bank.row_index(ctx.learner, table, state, lay.max_children), table

    def instance_rows(
        self, bank: TableBank, ctx: StepContext, inst: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Rows ``[B, A]`` of ``bank`` for the instances ``inst [B]`` and their tables ``[B]``.

        Padding slots (beyond a node's children) read 0.
        """
        idx, table = self.instance_index(bank, ctx, inst)
        return bank.read(idx, lookup(self.layout.table_child_valid, table)), table

    def attach_heads(self, **banks: TableBank) -> None:
        """Heads (``self.heads``) naming every table node's block of each of ``banks``."""
        self.heads = attach_table_heads(self, self.graph, self.layout, banks)

    def time_of(self, batch, steps: str = "steps", duration: str = "duration") -> torch.Tensor:
        """Time of the children of ``batch``: steps ``N`` (discrete) or durations (continuous)."""
        level = batch[LEVEL]
        return level[duration] if self.continuous else level[steps].float()

    def primitive_time(self, batch) -> torch.Tensor:
        """Time of the primitive steps of ``batch``: 1 each (discrete) or their durations."""
        prim = batch[PRIMITIVE]
        if self.continuous:
            return prim["duration"]
        return torch.ones_like(prim["reward"])


class ValuePolicy:
    """Chooses children from a learner's action values with an exploration strategy.

    Every step reserves one draw number per push level (``new_step``), and the ``k``-th push of
    a step reads draw ``k``: a row's random stream never depends on how many pushes other rows
    needed, so a population equals separate runs.

    Args:
        learner: provides ``action_values``.
        exploration: greedy, epsilon-greedy or Boltzmann.
        rng: random numbers for the rows (one stream per row).
    """

    def __init__(self, learner: Learner, exploration: Exploration, rng: BatchRNG) -> None:
        self.learner = learner
        self.exploration = exploration
        self.rng = rng
        self._first = 0

    def new_step(self) -> None:
        """Reserve this step's draws, one per push level."""
        self._first = self.rng.reserve(self.learner.graph.max_levels)

    def select(
        self, inst: torch.Tensor, ctx: StepContext, available: torch.Tensor, step: int, push: int
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(child slot [B], greedy flag [B])`` for the ``push``-th push of the step."""
        q = self.learner.action_values(inst, ctx)
        u = self.rng.uniform(uniforms_needed(q.shape[-1]), counter=self._first + push)
        return self.exploration.select(q, available, u, step)
