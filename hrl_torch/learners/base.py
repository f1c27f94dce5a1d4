"""What every learner provides, and the policy that turns its values into choices.

A learner is an update rule over batches of SMDP transitions (see ``hrl_torch.execution.executor``):

- ``evaluate(ctx)`` computes, once per step, whatever per-node values its choices and targets
  need at the current observations and stores them in ``ctx.values``, under the keys its
  ``value_keys`` declare (all of them, no other: ``evaluate_checked`` holds it to them);
- ``action_values(inst, ctx)`` returns the values ``[B, A]`` of the children of the instances
  ``inst [B]`` that exploration chooses from;
- ``update(batch, step)`` applies one batch of transitions (``hrl_torch.training.agent``): their
  ``batch["values"]`` holds what ``evaluate`` computed at ``s'``, ``batch["obs"]`` is ``s'``.

Learners never step envs and never touch the Task-Stack.
"""

from __future__ import annotations

import torch
from torch import nn

from hrl_torch.common.devices import MovesTensorAttrs, static_shapes
from hrl_torch.common.ops import RowLayout, add_at, at_rows, lookup, row_layout, take_flat
from hrl_torch.common.per_learner import check_size
from hrl_torch.common.rng import BatchRNG, LevelDraws
from hrl_torch.execution.transitions import LEVEL, PRIMITIVE, Choice
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.learners.validate import check_fraction, check_step_size
from hrl_torch.modules.eval_plan import EvalPlan
from hrl_torch.modules.exploration import (
    Exploration,
    has_per_learner_values,
    on_device,
    uniforms_needed,
)
from hrl_torch.modules.heads import attach_table_heads
from hrl_torch.modules.schedules import Schedule, VisitCount, as_schedule
from hrl_torch.modules.tables import TableBank, TableLayout, TableSet


def finished(level) -> torch.Tensor:
    """``[B, D]``: the levels of a transition batch (``batch[LEVEL]``) that learn this step.

    A transition was emitted there and its child ended by its own termination, or ``s'`` is
    terminal for the level's node (an abort by an ancestor teaches nothing).
    """
    return level["valid"] & (level["child_done"] | level["terminal"])


class Learner(MovesTensorAttrs, nn.Module):
    """Base class: a population of ``P`` independent learners over one task graph.

    ``uses``: the optional transition keys ``update`` reads
    (``hrl_torch.execution.executor.HierarchicalExecutor.OPTIONAL``); ``None`` (the default) asks
    for all of them, a learner that declares fewer spares the executor their ops.
    """

    gamma: float = 1.0
    uses: frozenset[str] | None = None
    #: the keys ``evaluate`` writes in ``ctx.values`` (every one, every step), which ``update``
    #: reads back from ``batch["values"]``: a key not declared here is never in a batch
    value_keys: tuple[str, ...] = ()
    #: ``evaluate``'s values at a row depend on nothing but the row's learner, the tables, the
    #: context's fields and the observation (not, e.g., on the executor's stacks): on a
    #: tabulated graph a function of the row's learner and state, which lets a non-learning
    #: agent look them up (``FrozenValues``)
    values_per_state: bool = False
    #: ``update`` reads ``batch["values"]`` only at the levels that learn (``finished``) and
    #: nothing of ``batch["obs"]``: values elsewhere may be stale (the sequential broadcast
    #: then skips a context for the targets that no learning level reads)
    targets_at_finished_levels: bool = False
    #: ``instance_action_values(ctx)`` gives every instance's action values at once
    #: (``ValuePolicy`` then chooses for every chooser in one go)
    all_instances_at_once: bool = False
    #: width ``K`` of the likelihood-ratio terms its policy returns (PG nodes; 0: none)
    score_width: int = 0
    #: masks over every row instead of compacting rows (``None``: ``devices.static_shapes``)
    static_rows: bool | None = None

    def static(self, device: torch.device) -> bool:
        """Whether an update on ``device`` keeps static shapes (no host read) or compacts."""
        return static_shapes(device) if self.static_rows is None else self.static_rows

    def __init__(self, graph: TaskGraph, n_learners: int) -> None:
        super().__init__()
        self.graph = graph
        self.n_learners = n_learners
        # |TD error| sums and counts per learner and node since the last log (saved: a resumed
        # run logs what an uninterrupted one would)
        self.register_buffer("td_abs", torch.zeros(n_learners, graph.n_nodes))
        self.register_buffer("td_count", torch.zeros(n_learners, graph.n_nodes))

    def evaluate(self, ctx: StepContext) -> None:
        """Fill ``ctx.values`` for the observations of ``ctx`` (the keys of ``value_keys``)."""

    def evaluate_checked(self, ctx: StepContext) -> None:
        """``evaluate``, then a clear error when ``ctx.values`` is not keyed by ``value_keys``."""
        self.evaluate(ctx)
        if ctx.values.keys() != set(self.value_keys):
            raise KeyError(
                f"{type(self).__name__}.evaluate wrote ctx.values keys {_names(ctx.values)}, "
                f"but its value_keys declare {_names(self.value_keys)}"
            )

    def update_checked(self, batch, step: int) -> None:
        """``update``; a missing key names what the batch's values hold (``value_keys``)."""
        try:
            self.update(batch, step)
        except KeyError as err:
            raise KeyError(
                f"{type(self).__name__}.update: {err.args[0] if err.args else err}; its batch "
                f"values hold its value_keys {_names(self.value_keys)} only"
            ) from err

    def make_policy(self, exploration: Exploration, rng: BatchRNG, evaluate: bool = False):
        """The executor policy: ``exploration`` over the action values (``ValuePolicy``).

        Policy-gradient and hybrid learners supply their own (PG nodes sample from their
        heads; ``evaluate`` asks for the evaluation policy, PG nodes acting on their modes).
        """
        return ValuePolicy(self, exploration, rng)

    def value_nodes(self) -> set[int] | None:
        """The nodes this learner chooses for by values, if it keeps only some (else ``None``)."""
        return None

    def action_values(self, inst: torch.Tensor, ctx: StepContext) -> torch.Tensor:
        """Values ``[B, A]`` of the children of ``inst [B]`` (padding slots are ignored)."""
        raise NotImplementedError

    def update(self, batch, step: int) -> None:
        """Learn from one batch of transitions (values at ``s'`` in ``batch["values"]``)."""
        raise NotImplementedError

    def record_td(
        self, learner: torch.Tensor, node: torch.Tensor, error: torch.Tensor, mask: torch.Tensor
    ) -> None:
        """Accumulate ``|error|`` per (learner, node) where ``mask`` (shapes broadcast)."""
        m = mask.float()
        add_at(self.td_abs, (learner, node), error.abs().nan_to_num() * m)
        add_at(self.td_count, (learner, node), m)

    def deferred_checks(self) -> list:
        """Turn on deferral of this learner's own step checks; the ``DeferredCheck``s (none)."""
        return []

    def ring_entries(self, rows: int) -> int:
        """Trace-ring entries a step reads for ``rows`` batch rows (0: no rings)."""
        return 0

    def know_rows(self, learner: torch.Tensor, layout: RowLayout) -> None:
        """Be told the layout of the rows ``learner [B]`` (an agent's, read on the CPU)."""
        known = self.__dict__.setdefault("_known_rows", {})
        known[id(learner)] = (learner, layout)  # (keeps the tensor: its id is not reused)
        while len(known) > 8:  # each evaluation's agent brings new rows
            known.pop(next(iter(known)))

    def row_layout(self, learner: torch.Tensor) -> RowLayout | None:
        """The ``RowLayout`` of the rows ``learner [B]``: told (``know_rows``) or read once.

        ``None`` on ``meta`` for rows nobody told of (no data to read).
        """
        known = self.__dict__.setdefault("_known_rows", {})
        rows, layout = known.get(id(learner), (None, None))
        if rows is not learner:
            if learner.device.type == "meta":
                return None
            self.know_rows(learner, row_layout(learner, learner.device))
            layout = known[id(learner)][1]
        return layout

    def rows_distinct(self, learner: torch.Tensor) -> bool:
        """Whether every row of a batch belongs to another learner (``learner [B]``).

        Then no two rows reach one table entry.
        """
        layout = self.row_layout(learner)
        return layout is not None and layout.distinct


def _names(keys) -> str:
    return ", ".join(sorted(keys)) or "(none)"


class TabularLearner(Learner):
    """Shared machinery of the tabular value learners: layout, banks and the step size.

    Every step a tabular learner reads the rows of all its non-primitive tables at the current
    states with one gather per bank (``composite_rows``), evaluates them bottom-up over height
    groups (``self.plan``), and keeps the rows its choices read in ``ctx.values["Q"]``
    ``[B, Tc, A]`` (``action_values`` gathers them per instance).

    Their values are functions of the context's fields and the tables (``values_per_state``; a
    subclass whose ``evaluate`` reads more than the row's learner and observation sets it
    False).

    Args:
        graph: the task graph.
        n_learners: population size ``P``.
        alpha: step size (number or schedule over env steps), or ``VisitCount(low, high)``:
            each table entry its own ``clip(1 / n, low, high)`` over its ``n`` updates (the
            banks then count visits; docs/defaults.md, "Step sizes that settle").
        gamma: discount factor (1 for undiscounted episodic tasks).
        per_instance: tables per Task-Stack context instead of per subtask.
    """

    values_per_state = True
    all_instances_at_once = True
    value_keys = ("Q",)

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
        check_size(self, "alpha", alpha, n_learners)  # a per-learner alpha: one per learner
        check_fraction(self, "gamma", gamma)
        self.alpha = as_schedule(alpha)
        self.counts_visits = isinstance(alpha, VisitCount)  # (the banks count their entries')
        self.gamma = float(gamma)
        self.layout = TableLayout(graph, per_instance)
        self.plan = EvalPlan(graph, self.layout)
        self.continuous = False  # continuous-time learners measure time by durations

    def completion_bank(self, init: float = 0.0) -> TableBank:
        """A ``[n_states, n_children]`` table for every non-primitive table node."""
        lay = self.layout
        n_states = torch.where(lay.table_is_primitive, 0, lay.table_n_states)
        n_cols = lay.table_n_children.clamp_min(1)
        return TableBank(
            self.n_learners, n_states, n_cols, init, pad=lay.max_children, visits=self.counts_visits
        )

    def primitive_bank(self, init: float = 0.0) -> TableBank:
        """A ``[n_states, 1]`` value table for every primitive table node."""
        lay = self.layout
        n_states = torch.where(lay.table_is_primitive, lay.table_n_states, 0)
        ones = torch.ones_like(n_states)
        return TableBank(self.n_learners, n_states, ones, init, visits=self.counts_visits)

    # ------------------------------------------------------------------ evaluation
    def composite_rows(self, ctx: StepContext, *banks: TableBank, penalty: bool = False):
        """The planned tables' rows at ``ctx``: ``(blocked, dead, rows of each bank)``.

        ``blocked [B, Tc, A]``: children not available (padding True); ``dead [B, Tc]``: the
        table's state is terminal for it or nothing is available (its value is 0); each bank's
        rows ``[B, Tc, A]`` (tables in ``self.plan`` order). The entries of blocked children
        hold any finite value: read them masked. The banks share one layout (completion banks
        of this learner, padded by ``max_children``). ``penalty``: ``blocked`` as floats, -inf
        where blocked and 0 elsewhere (``EvalPlan.rows_at``).
        """
        blocked, dead, index = self.plan.rows_at(ctx, banks[0], penalty)
        rows = []
        for bank in banks:
            at = index if bank.base == banks[0].base else index + (bank.base - banks[0].base)
            rows.append(take_flat(bank.store, at))
        return blocked, dead, rows

    def primitive_values(self, ctx: StepContext, bank: TableBank) -> torch.Tensor:
        """``[B, T]``: ``bank``'s values of the primitive tables at ``ctx`` (0 elsewhere)."""
        values = take_flat(bank.store, self.plan.prim_index_at(ctx, bank))
        value = torch.zeros(values.shape[0], self.layout.n_tables, device=values.device)
        return value.index_copy_(1, self.plan.prims, values)

    def groups(self, *per_table: torch.Tensor):
        """Per height group, bottom-up: ``(table ids [G], children [B, G, A], parts...)``.

        ``per_table``: tensors ``[B, Tc, ...]`` in plan order, split into the groups' parts;
        ``children``: where each child's value is in a ``[B, T]`` value tensor (``take``).
        """
        plan = self.plan
        parts = [x.split(plan.sizes, 1) for x in per_table]
        kids = plan.child_index(per_table[0].shape[0])
        yield from zip(plan.group_ids, kids, *parts, strict=True)

    def action_values(
        self, inst: torch.Tensor, ctx: StepContext, rows: torch.Tensor | None = None
    ) -> torch.Tensor:
        """The rows ``ctx.values["Q"]`` of the instances ``inst [B]``: ``[B, A]``.

        With ``rows [R]``: ``inst [R]`` are the instances of those batch rows.
        """
        q = ctx.values["Q"]
        if rows is None:
            return at_rows(q, lookup(self.plan.inst_pos, inst))
        flat = q.reshape(q.shape[0] * q.shape[1], q.shape[2])
        return flat.index_select(0, rows * q.shape[1] + lookup(self.plan.inst_pos, inst))

    def instance_action_values(self, ctx: StepContext) -> torch.Tensor:
        """The rows of every choosing instance (``plan.choosers``): ``[B, Ic, A]``."""
        return ctx.values["Q"].index_select(1, self.plan.chooser_pos)

    # ------------------------------------------------------------------ updates
    def table_index(self, bank: TableBank, learner, inst, state, col) -> torch.Tensor:
        """Flat indices into ``bank`` of ``(instance's table, state, col)`` (broadcast)."""
        table = lookup(self.layout.inst_table, inst.clamp_min(0))
        return bank.index(learner, table, state, col)

    def level_table(self, level) -> torch.Tensor:
        """The table of every level of a transition batch ``[B, D]``.

        A per-subtask table is the level's node; a per-instance one its instance.
        """
        return level["inst"].clamp_min(0) if self.layout.per_instance else level["node"]

    def share_store(self, **banks: TableBank) -> None:
        """Keep ``banks`` in one store (``self.tables``) so that one update reaches them all.

        ``entry_index`` then gives each level's entry of its own table in one index: ``C`` of
        the node whose child ended, ``V`` of the primitive that ran (the first two banks).
        """
        self.tables = TableSet(**banks)
        composite, primitive = list(banks.values())[:2]
        prim = self.layout.table_is_primitive
        offset = torch.where(prim, primitive.offset, composite.offset)
        self.register_buffer("entry_offset", offset, persistent=False)
        n_cols = torch.where(prim, primitive.n_cols, composite.n_cols)
        self.register_buffer("entry_cols", n_cols, persistent=False)

    def entry_index(self, learner: torch.Tensor, level, table: torch.Tensor) -> torch.Tensor:
        """``[B, D]`` flat indices of each level's entry at its start state and child.

        A non-primitive level's ``C(i, s, a)``, the primitive level's ``V(a, s)`` (its child
        slot is 0); ``share_store`` made the layout. ``learner [B]``, ``level`` the
        transitions' levels (``batch[LEVEL]``).
        """
        base = self.plan.learner_base(learner, self.tables.stride, 2)
        offset, n_cols = torch.take(self.entry_offset, table), torch.take(self.entry_cols, table)
        return base + offset + level["state"] * n_cols + level["child"]

    def update_visited(self, batch, table, valid, alpha, targets) -> None:
        """All-states updating (Algorithm 1 line 16, Algorithm 2 line 15, Algorithm 4 line 16).

        Every state ``s_k`` a finished child passed after its first step (the executor's
        ``visited_state [B, D, K]``) gets an update of its own: each ``(bank, target [B, D, K])``
        of ``targets`` moves entry ``(table, s_k, child)`` toward the target from ``s_k``, at
        the levels ``valid [B, D]``. The banks share one layout (completion banks of one store).
        """
        level = batch[LEVEL]
        late = level["visited_valid"] & (level["visited_steps"] > 0) & valid[..., None]
        late = late.reshape(-1)
        first = targets[0][0]
        learner = batch["learner"][:, None, None]
        state, child = level["visited_state"], level["child"][..., None]
        index = first.index(learner, table[..., None], state, child).reshape(-1)
        for bank, target in targets:
            at = index if bank.base == first.base else index + (bank.base - first.base)
            bank.update(at, target.reshape(-1), alpha, late)

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

    Every step takes one draw of the rows' random streams (``new_step``): a block of uniforms
    per stack level that can choose, and a choice made at level ``l`` reads block ``l``: a
    row's random stream never depends on what other rows do, so a population equals separate
    runs. Tabular learners (``instance_action_values``)
    choose for every choosing instance at once (``choose_all``); the executor then follows
    those choices down the stack. Other learners are asked level by level (``select``).

    Args:
        learner: provides ``action_values`` (and optionally ``instance_action_values``).
        exploration: greedy, epsilon-greedy or Boltzmann.
        rng: random numbers for the rows (one stream per row).

    Attributes:
        choice_cost: optional ``[n_nodes, max_children]`` cost of choosing a child, subtracted
            from its action value before the choice (not learned; e.g. the communication cost
            of COM-Cooperative HRL, ``hrl_torch.multiagent.cooperative.Communication``).
    """

    #: on the CPU, above this many values per step (rows x choosers x children), choosing
    #: level by level (fewer values, more ops) is faster than choosing for every chooser at
    #: once (measured on taxi: equal at 320 rows, 20% faster at 5,120)
    ALL_AT_ONCE_LIMIT = 1 << 16

    def __init__(self, learner: Learner, exploration: Exploration, rng: BatchRNG) -> None:
        g = learner.graph
        self.learner = learner
        self.exploration = on_device(exploration, g.chooser_depth.device)
        self.rng = rng
        self.choice_cost: torch.Tensor | None = None
        self.per_learner = has_per_learner_values(exploration)  # choices read rows' learners
        self.width = uniforms_needed(g.max_children)
        self.all_at_once = learner.all_instances_at_once
        self.draws = LevelDraws(rng, g, self.width)
        # every chooser reads its level's block
        cols = g.host("chooser_depth")[:, None] * self.width + torch.arange(self.width)
        self._chooser_columns = cols.to(g.chooser_depth.device)
        rng.know_columns(self._chooser_columns, cols.reshape(-1).tolist())  # (no read per block)

    def new_step(self) -> None:
        """Take this step's draw (read by the choices)."""
        self.draws.new_step()

    def select(
        self, inst: torch.Tensor, ctx: StepContext, available: torch.Tensor, step: int, push: int
    ) -> Choice:
        """The choices for instances ``inst [B]`` at stack level ``push``."""
        q = self.learner.action_values(inst, ctx)
        if self.choice_cost is not None:
            q = q - self.choice_cost[self.learner.graph.inst_node[inst]]
        u = self.draws.level(push)
        return Choice(*self.exploration.select(q, available, u, step, ctx.learner))

    def select_rows(self, inst, ctx: StepContext, available, step: int, push: int, rows):
        """``select`` for the batch rows ``rows [R]`` only (``inst``, ``available`` theirs).

        The same choices as ``select``'s at those rows; only their numbers are drawn.
        """
        q = self.learner.action_values(inst, ctx, rows)
        if self.choice_cost is not None:
            q = q - self.choice_cost[self.learner.graph.inst_node[inst]]
        u = self.draws.level_rows(push, rows)
        learner = ctx.learner.index_select(0, rows) if self.per_learner else None
        return Choice(*self.exploration.select(q, available, u, step, learner))

    def choose_all(self, ctx: StepContext, step: int) -> Choice | None:
        """The choices ``[B, Ic]`` of every choosing instance (``graph.choosers``).

        The instance at depth ``d`` reads the uniforms of level ``d``. ``None`` (the
        executor then asks ``select`` level by level, the same choices) for learners without
        ``instance_action_values`` and, on the CPU, above ``ALL_AT_ONCE_LIMIT``.
        """
        if not self.all_at_once:
            return None
        g = self.learner.graph
        values = ctx.learner.shape[0] * g.n_choosers * g.max_children
        if ctx.learner.device.type == "cpu" and values > self.ALL_AT_ONCE_LIMIT:
            return None
        q = self.learner.instance_action_values(ctx)
        if self.choice_cost is not None:
            q = q - self.choice_cost.index_select(0, g.chooser_node)
        available = ctx.available.index_select(1, g.chooser_node)
        u = self.draws.columns(self._chooser_columns)
        return Choice(*self.exploration.select(q, available, u, step, ctx.learner))
