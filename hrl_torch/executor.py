"""The batched Task-Stack executor (Section 3.2).

For every env row the executor keeps a Task-Stack of ``D`` levels (``hrl_torch.stack``): the
instance at each level, the child it chose, the abstract state where that child started and the
reward and time accumulated since. ``observe`` takes one env step: it accumulates rewards, pops
every level that ended (a terminating subtask aborts everything it called) and emits the
finished SMDP transitions as a TensorDict. ``act`` pushes children until a primitive is on top
and returns the primitive actions. The executor never updates values, and never writes into a
stack: each call replaces ``self.stack`` by a new one.

Transitions are a TensorDict ``[B]`` with ``learner [B]`` (learner of the row) and two nested
TensorDicts (their keys are the constants ``LEVEL`` and ``PRIMITIVE``):

``batch[LEVEL]`` ``[B, D]``, level ``j`` is the subtask whose child ended:

- ``valid``: a transition was emitted at this level;
- ``inst``, ``node``, ``child`` (slot in the node's children), ``parent_inst``;
- ``state`` / ``next_state``: abstract state of ``node`` when the child started / at ``s'``;
- ``steps`` (primitive steps ``N``), ``duration`` (time ``tau``), ``reward`` (external, summed),
  ``discounted_reward`` (sum of ``gamma**t r``), ``internal_reward`` (discounted shaping of
  ``node``), ``pseudo_reward`` (``node``'s pseudo reward if ``s'`` is terminal for it);
- ``terminal`` (``s'`` is terminal for ``node``), ``child_done`` (the child ended by its own
  termination, not by an abort), ``truncated`` (time limit), ``greedy`` (the child and all its
  ancestors were chosen greedily), ``own_greedy`` (the child was chosen greedily);
- ``ran``: the level holds the primitive that ran this step (its ``state`` is the primitive's
  own abstract state and ``child`` is 0), when the step teaches; the same step as
  ``batch[PRIMITIVE]``, placed on its level so that one update can reach ``C`` of the finished
  children and ``V`` of the primitive;
- with ``record_visited = L > 0``: ``visited_state``, ``visited_steps``, ``visited_time``,
  ``visited_internal`` ``[B, D, L]`` and their mask ``visited_valid``: the states of ``node``
  during the child, from where it started to the step before ``s'`` (all-states updating), the
  most recent ``L`` kept, with the steps, time and discounted shaping reward (of ``node``,
  discounted to the child's start) accumulated before each;
- with feature nodes (``Subtask.features``): ``features`` / ``next_features``
  ``[B, D, F]``, the node's continuous features where the child started / at ``s'``;
- with a policy that scores its choices (PG nodes): ``score_index`` / ``score_value``
  ``[B, D, K]``, the likelihood-ratio term of the child's choice.

``batch[PRIMITIVE]`` ``[B]``, the primitive step just taken: ``valid``, ``inst``, ``node``,
``state``, ``reward``, ``duration``, ``greedy`` (its parent and all ancestors chose greedily),
``action`` (the env action, ``[B, action_dim]`` in continuous action spaces).

Some keys are computed only when the executor's ``uses`` asks for them (``OPTIONAL``; a
learner names the ones it reads in ``Learner.uses``): ``parent_inst``, ``next_state``,
``truncated``, the greedy flags, and ``batch[PRIMITIVE]``'s fields other than ``reward`` and
``duration``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal, Protocol

import torch
from tensordict import TensorDict

from hrl_torch.graph import GraphError, StepContext, TaskGraph
from hrl_torch.ops import add_at, discount, entries
from hrl_torch.stack import TaskStack

#: key of the per-level transitions ``[B, D]`` in a transition batch
LEVEL = "level"
#: key of the primitive step ``[B]`` in a transition batch
PRIMITIVE = "primitive"


class SubtaskTimeoutError(RuntimeError):
    """A subtask ran more primitive steps than ``ExecutorConfig.max_subtask_steps``."""


@dataclass
class Choice:
    """A policy's choices for the ``B`` rows of one push.

    Attributes:
        child: chosen child slot ``[B]`` (ignored for rows that do not push).
        greedy: the choice is the policy's greedy one ``[B]``.
        action: ``[B, action_dim]``, the action value of rows whose child is a continuous
            primitive (graphs with continuous primitives), else ``None``.
        score_index: ``[B, K]`` flat parameter indices of the choice's likelihood-ratio term
            (policy-gradient nodes), kept on the stack until the child ends; else ``None``.
        score_value: ``[B, K]`` its values.
    """

    child: torch.Tensor
    greedy: torch.Tensor
    action: torch.Tensor | None = None
    score_index: torch.Tensor | None = None
    score_value: torch.Tensor | None = None


class Policy(Protocol):
    """Chooses children for the instances on top of the stacks.

    Besides ``select`` a policy may offer ``choose_all(ctx, step) -> Choice | None``: the
    choices ``[B, Ic]`` of every choosing instance (``graph.choosers``) at once, which the
    executor then follows down the stacks (``None``: ask ``select``); and
    ``select_rows(inst, ctx, available, step, push, rows) -> Choice``: ``select`` for the
    batch rows ``rows [R]`` only (``inst`` and ``available`` are theirs), the same choices as
    ``select`` makes for those rows, used on large CPU batches.
    """

    def new_step(self) -> None:
        """Called once at the start of every ``act`` (draw this step's random numbers)."""
        ...

    def select(
        self, inst: torch.Tensor, ctx: StepContext, available: torch.Tensor, step: int, push: int
    ) -> Choice:
        """The choices for instances ``inst [B]`` among ``available [B, A]`` children.

        ``push`` is the stack level (depth) of the instances that choose; rows whose instance
        does not choose at this level get any value (ignored). (A tuple ``(child, greedy[,
        action])`` is accepted too.)
        """
        ...


@dataclass
class ExecutorConfig:
    """Executor options.

    Attributes:
        max_subtask_steps: guard: primitive steps one invocation of a non-root subtask may take.
        on_timeout: ``"raise"`` a ``SubtaskTimeoutError``, or ``"abort"`` the subtask (and
            what it called) and carry on; aborted children produce no learning target.
        record_visited: keep the last ``L`` states visited during each child for all-states
            updating (0 = off).
        on_bad_step: an env step with a non-finite reward or a non-finite or negative
            duration: ``"raise"`` a ``BadStepError``, or ``"skip"`` it: nothing is learned from
            it, every subtask running in that row is aborted (no learning target), the row
            starts again at the root in its new state, and ``skipped_steps`` counts it per
            learner.
    """

    max_subtask_steps: int = 10_000
    on_timeout: Literal["raise", "abort"] = "raise"
    record_visited: int = 0
    on_bad_step: Literal["raise", "skip"] = "raise"


class BadStepError(ValueError):
    """An env step with a non-finite reward or a non-finite or negative duration."""


class HierarchicalExecutor:
    """Task-Stacks for ``B`` env rows over one task graph (``self.stack``, a ``TaskStack``).

    Args:
        graph: the task graph.
        batch_size: ``B``.
        envs_per_learner: ``E`` (row ``b`` belongs to learner ``b // E``).
        gamma: discount used for ``discounted_reward`` / ``internal_reward``.
        config: guard and all-states options.
        learner: the learner of each row ``[B]`` instead of ``b // E`` (multi-agent rows).
        score_width: width ``K`` of the likelihood-ratio terms the policy returns (0: none).
        uses: the optional transition keys the consumers read (``OPTIONAL``), ``None``: all.
            The others are left out of the transitions, and the greedy flags are not kept
            on the stacks unless ``"greedy"`` is in ``uses``.
        count_stats: keep the subtask statistics (``stats``; off for evaluation agents).
    """

    #: transition keys computed only when asked for (``uses``): ``batch[LEVEL]``'s
    #: ``parent_inst``, ``next_state``, ``truncated``; ``"greedy"`` for the greedy flags
    #: (``greedy``, ``own_greedy`` of both parts); ``"primitive"`` for ``batch[PRIMITIVE]``'s
    #: fields other than ``reward`` and ``duration``
    OPTIONAL = frozenset({"parent_inst", "next_state", "truncated", "greedy", "primitive"})

    def __init__(
        self,
        graph: TaskGraph,
        batch_size: int,
        envs_per_learner: int | None = None,
        gamma: float = 1.0,
        config: ExecutorConfig | None = None,
        learner: torch.Tensor | None = None,
        score_width: int = 0,
        uses: frozenset[str] | None = None,
        count_stats: bool = True,
    ) -> None:
        self.uses = self._checked_uses(uses)
        self.graph = graph
        self.config = config or ExecutorConfig()
        self.gamma = float(gamma)
        self.batch_size = batch_size
        device = graph.node_children.device
        self.device = device
        long = dict(dtype=torch.long, device=device)
        if learner is None:
            learner = torch.arange(batch_size, **long) // (envs_per_learner or batch_size)
        self.learner = learner.to(device)
        self.envs_per_learner = envs_per_learner or batch_size
        self.n_learners = int(self.learner.max()) + 1 if batch_size else 0
        self.depth = graph.max_levels
        self.levels = torch.arange(self.depth, **long)
        self.rows = torch.arange(batch_size, **long)
        self.score_width = score_width
        self._guard_quiet = 0  # steps during which no invocation can reach the guard
        self.stack = TaskStack.empty(
            graph, batch_size, max(self.config.record_visited, 1), score_width
        )
        self._visit_slots = torch.arange(max(self.config.record_visited, 1), **long)
        self._row_base = self.rows * graph.n_nodes  # row b's block in a flat [B * N, ...]
        self._init_descent()
        # the per-level sums a new child restarts (the discounted sums are the plain ones when
        # gamma is 1; the internal ones stay 0 without shaping rewards)
        self._accumulators = ["steps", "time", "reward"]
        if self.gamma != 1.0:
            self._accumulators.append("disc_reward")
        if graph.shaping_nodes:
            self._accumulators.append("internal")
        self._no_reward = torch.zeros(batch_size, self.depth, device=device)
        self._spans, self._span_code_1 = _level_spans(self.depth, graph.inst_depth_1)
        self._memory_depth = _memory_feature_depth(graph)
        self._obs = None
        self._action = torch.zeros(batch_size, **long)
        self._acting: torch.Tensor | None = None  # agent rows acting at this step (observe)
        #: ``interrupt(popped [B, D], ended_own [B, D]) -> [B, D]``: more levels to cut
        self.interrupt = None
        self.stats = ExecutorStats(self.learner, self.n_learners, graph.n_nodes)
        self.count_stats = count_stats
        #: env steps skipped per learner (``on_bad_step="skip"``)
        self.skipped_steps = torch.zeros(self.n_learners, device=device)
        #: levels ``[B, D]`` whose node was invoked by the last ``act``
        self.invoked = torch.zeros_like(self.stack.inst, dtype=torch.bool)

    @classmethod
    def _checked_uses(cls, uses: frozenset[str] | None) -> frozenset[str]:
        """``uses`` (``None``: every optional key); an unknown key is a ``ValueError``."""
        unknown = set(uses or ()) - cls.OPTIONAL
        if unknown:
            raise ValueError(
                f"unknown transition keys {sorted(unknown)}; optional ones: {sorted(cls.OPTIONAL)}"
            )
        return cls.OPTIONAL if uses is None else frozenset(uses)

    def _init_descent(self) -> None:
        """The descent's index bases (``_descend``): each row's block of choices, codes, flags."""
        g, long = self.graph, dict(dtype=torch.long, device=self.device)
        ic, codes = g.n_choosers, g.n_choosers + g.n_instances + 1
        self._chooser_base = (torch.arange(ic, **long) * g.max_children)[None, :]
        self._leaf_codes = torch.arange(ic, codes, **long).expand(self.batch_size, -1)
        self._code_base = self.rows * codes
        self._greedy_base = self.rows[:, None] * (ic + 1)

    @property
    def stack(self) -> TaskStack:
        """The Task-Stacks of the rows (replaced, never written, by ``observe`` and ``act``).

        (The executor keeps the fields as a dict and makes the ``TaskStack`` when asked.)
        """
        if self._stack is None:
            self._stack = TaskStack.from_tensors(self._fields, self.batch_size)
        return self._stack

    @stack.setter
    def stack(self, stack: TaskStack) -> None:
        self._stack, self._fields = stack, stack.tensors()
        self._guard_quiet = 0  # stacks from elsewhere: check the guard at the next step

    def _replace(self, fields: dict) -> None:
        """Take ``fields`` (new tensors, the old ones untouched) as the stacks."""
        self._fields, self._stack = fields, None

    @property
    def memory(self) -> torch.Tensor:
        """What each node's running invocation remembered ``[B, n_nodes, M]`` (for contexts)."""
        return self._fields["memory"]

    def reset(self) -> None:
        """Empty every stack (all rows start at the root on the next ``act``)."""
        self.stack = self.stack.cleared()

    # ------------------------------------------------------------------ acting
    def act(self, ctx: StepContext, policy: Policy, step: int) -> torch.Tensor:
        """Push children until a primitive is on top of every live stack; return actions ``[B]``.

        Rows whose stack is empty and whose episode is not over start at the root. From the
        instance on top, each row descends by its policy's choices until a primitive is on top;
        the stack is then the primitive's path from the root (``graph.path_*``). A policy with
        ``choose_all`` chooses for every choosing instance of a row at once (the choice at
        depth ``d`` reading the row's random numbers of level ``d``), and the descent follows
        those choices; otherwise the policy's ``select`` is asked level by level.
        """
        g, f = self.graph, dict(self._fields)
        policy.new_step()
        # a node that remembers where it started sees its features relative to that start:
        # a new invocation's come from what it remembers now, not from the previous one's
        new_features = None
        if self._memory_depth >= 0 and ctx.features is not None:
            # computed for the rows whose stack ends above a level where such a node can start
            rows = (f["top"] < self._memory_depth).nonzero().squeeze(1)
            if rows.numel():
                started = g.start_features(ctx.obs[rows], ctx.features.index_select(0, rows))
                new_features = ctx.features.index_copy(0, rows, started)
        choose_all = getattr(policy, "choose_all", None)
        choice = choose_all(ctx, step) if choose_all is not None else None
        if choice is not None:
            top1, own_greedy = self._descend(f, choice, "greedy" in self.uses)
        else:
            top1, own_greedy = self._descend_level_by_level(f, ctx, policy, step, new_features)
        self._push(f, ctx, top1, own_greedy, new_features)
        self._replace(f)
        self._acting = None
        if g.action_dim:
            self._action = torch.where((f["top"] >= 0)[:, None], f["cont_action"], 0.0)
        else:
            self._action = torch.take(g.inst_action_1, top1)
        self._obs = ctx.obs
        return self._action

    def _start_code(self, f: dict) -> torch.Tensor:
        """Where each row's descent starts ``[B]`` (a descent code, ``graph._compile_paths``).

        The instance on top (the root for an empty stack); nothing for a row waiting for its
        reset and for an agent row that does not act (its primitive stays on top).
        """
        g = self.graph
        top = f["inst"].amax(1)  # ids grow along a path: the top is the largest (-1: none)
        code = torch.take(g.inst_start_code, top).masked_fill(f["done"], g.n_choosers)
        if self._acting is not None:
            code = torch.where(self._acting, code, g.n_choosers + 1 + top)
        return code

    def _descend(self, f: dict, choice: Choice, greedy: bool = True):
        """Follow the choices of every choosing instance ``[B, Ic]`` down to a primitive.

        Returns the instance on top + 1 ``[B]`` and each level's choice greedy flag on the
        new stack ``[B, D]`` (True where nothing was chosen; ``None`` without ``greedy``).
        """
        g, ic = self.graph, self.graph.n_choosers
        nxt = torch.take(g.chooser_next_code, self._chooser_base + choice.child)
        nxt = torch.cat([nxt, self._leaf_codes], 1)  # a primitive stays where it is
        code = self._start_code(f)
        for _ in range(self.depth - 1):
            code = torch.take(nxt, self._code_base + code)  # (take reads nxt flat)
        top1 = code - ic
        if not greedy:
            return top1, None
        flags = torch.nn.functional.pad(choice.greedy, (0, 1), value=True)
        own = torch.take(flags, self._greedy_base + g.path_chooser_1.index_select(0, top1))
        return top1, own

    def _descend_level_by_level(self, f, ctx, policy, step, new_features=None):
        """``_descend`` with the policy's ``select`` asked once per level (any policy).

        The choice of the instance at depth ``d`` reads the row's random numbers of level
        ``d`` (``push=d``); a policy's scores and continuous actions are kept on the stack.
        ``new_features``: the features ``[B, N, F]`` of new invocations
        (``graph.start_features``), which the rows whose instance at ``d`` was pushed in this
        act choose from. On large CPU batches a policy with ``select_rows`` chooses for the
        rows that choose at a level only (the same choices, fewer values).
        """
        g = self.graph
        ic = g.n_choosers
        code = self._start_code(f)  # back to instances + 1 (0: none)
        col = torch.where(code < ic, torch.take(g.choosers, code.clamp_max(ic - 1)) + 1, code - ic)
        compact = (
            hasattr(policy, "select_rows")
            and self.device.type == "cpu"
            and self.batch_size >= self.COMPACT_ROWS
        )
        flags, scores = [], []
        for level in range(self.depth - 1):
            node = torch.take(g.inst_node_1, col)
            at_level = torch.take(g.inst_depth_1, col) == level
            chooses = torch.take(g.inst_composite_1, col) & at_level
            seen = ctx
            if new_features is not None:  # rows whose instance at this level started now
                started = (level > f["top"])[:, None, None]
                seen = replace(ctx, features=torch.where(started, new_features, ctx.features))
            if compact:
                choice, child = self._choose_rows(seen, policy, step, level, col, node, chooses)
            else:
                available = self._available_flat(ctx).index_select(0, self._row_base + node)
                choice = _as_choice(
                    policy.select((col - 1).clamp_min(0), seen, available, step, level)
                )
                child = torch.take(g.inst_children_1, col * g.max_children + choice.child)
            if choice.score_index is not None:
                scores.append((level, chooses, choice))
            if g.action_dim:
                self._record_action(f, chooses & ~torch.take(g.inst_composite_1, child), choice)
            col = torch.where(chooses, child, col)
            flags.append(choice.greedy | ~chooses)
        flags.append(torch.ones_like(col, dtype=torch.bool))
        own = torch.stack(flags, 1)
        if scores:
            self._record_scores(f, scores)
        return col, own

    #: from this many rows on (CPU), the level-by-level choices are made for the rows that
    #: choose at the level only (``policy.select_rows``)
    COMPACT_ROWS = 1024

    def _choose_rows(self, ctx, policy, step, level, col, node, chooses):
        """One level's choices, made for the rows that choose only: ``(choice, child)``.

        ``choice`` holds every row's values (0, greedy, no score where a row does not
        choose), ``child`` the chosen instance + 1 of every choosing row.
        """
        g = self.graph
        rows = chooses.nonzero().squeeze(1)
        inst1, node = col.index_select(0, rows), node.index_select(0, rows)
        available = self._available_flat(ctx).index_select(0, rows * g.n_nodes + node)
        part = _as_choice(
            policy.select_rows((inst1 - 1).clamp_min(0), ctx, available, step, level, rows)
        )
        child = torch.take(g.inst_children_1, inst1 * g.max_children + part.child)

        def spread(values: torch.Tensor, fill=0) -> torch.Tensor:
            """``values [R, ...]`` at ``rows`` of a ``[B, ...]`` tensor of ``fill``."""
            out = values.new_full((col.shape[0], *values.shape[1:]), fill)
            return out.index_copy(0, rows, values)

        out = Choice(spread(part.child), spread(part.greedy, True))
        if part.action is not None:
            out.action = spread(part.action)
        if part.score_index is not None:
            out.score_index, out.score_value = spread(part.score_index), spread(part.score_value)
        return out, spread(child)

    def _available_flat(self, ctx: StepContext) -> torch.Tensor:
        """``ctx.available`` as ``[B * N, A]`` rows (row ``b * N + node``)."""
        return ctx.available.view(-1, self.graph.max_children)

    def _record_scores(self, f: dict, scores: list) -> None:
        """Keep each choice's likelihood-ratio term at its level, where the level chose.

        ``scores``: ``(level, chose [B], choice)`` of the levels whose choices carry terms;
        one write for all levels.
        """
        for _, _, choice in scores:
            if choice.score_index.shape[1] != self.score_width:
                raise ValueError(
                    f"the policy scored its choices with {choice.score_index.shape[1]} entries, "
                    f"the executor keeps score_width={self.score_width}"
                )
        old_index, old_value = f["score_index"], f["score_value"]
        by_level = {level: (chose, choice) for level, chose, choice in scores}
        none = torch.zeros_like(old_index[:, 0, 0], dtype=torch.bool)
        chose = torch.stack(
            [by_level[k][0] if k in by_level else none for k in range(self.depth)], 1
        )
        new = [by_level.get(k, (None, None))[1] for k in range(self.depth)]
        index = torch.stack([c.score_index if c else old_index[:, k] for k, c in enumerate(new)], 1)
        value = torch.stack([c.score_value if c else old_value[:, k] for k, c in enumerate(new)], 1)
        f["score_index"] = torch.where(chose[..., None], index, old_index)
        f["score_value"] = torch.where(chose[..., None], value, old_value)

    @staticmethod
    def _record_action(f: dict, pushed: torch.Tensor, choice: Choice) -> None:
        """The action vector of the continuous primitives pushed (``pushed [B]``)."""
        if choice.action is None:
            raise GraphError("a continuous primitive was chosen without an action value")
        f["cont_action"] = torch.where(pushed[:, None], choice.action, f["cont_action"])

    def _push(self, f: dict, ctx: StepContext, top1, own_greedy, new_features=None) -> None:
        """The stacks of the instances ``top1 - 1`` on top, with their fresh levels set.

        Levels from the old top to the new one are fresh: the ones below the new top chose a
        new child (accumulators restart), the ones above the old top are new invocations (the
        root too on a row that starts). Levels below the old top keep what they had.
        """
        g = self.graph
        # the levels' roles, looked up by (old top, new top); -1 on a row that starts: its
        # root is fresh too
        span = f["top"] * (self.depth + 1) + torch.take(self._span_code_1, top1)
        kept, chose, invoked, fresh = self._spans.index_select(0, span).unbind(1)
        f["inst"] = g.path_inst_1.index_select(0, top1)
        f["node"] = node = g.path_node_1.index_select(0, top1)
        f["top"] = torch.take(g.inst_depth_1, top1)
        if not g.never_stuck:
            stuck = chose & ~ctx.available.any(-1).gather(1, node)
            if stuck.any().tolist():
                _raise_stuck(g, stuck, node)
        f["child"] = torch.where(kept, f["child"], g.path_child_1.index_select(0, top1))
        if own_greedy is not None:
            f["own_greedy"] = own = torch.where(kept, f["own_greedy"], own_greedy)
            f["greedy"] = own.cummin(1).values  # the level's own choice and every ancestor's
        f["start_state"] = torch.where(fresh, ctx.abstract.gather(1, node), f["start_state"])
        for key in self._accumulators:
            f[key] = f[key].masked_fill(chose, 0)
        if self.gamma == 1.0:
            f["disc_reward"] = f["reward"]
        f["inv_steps"] = f["inv_steps"].masked_fill(invoked, 0)
        if ctx.features is not None:
            at = node[..., None].expand(-1, -1, ctx.features.shape[2])
            feats = ctx.features.gather(1, at)
            if new_features is not None:  # a new invocation starts from what it remembers now
                feats = torch.where(invoked[..., None], new_features.gather(1, at), feats)
            f["start_features"] = torch.where(chose[..., None], feats, f["start_features"])
        if self.config.record_visited:
            first_visit = chose[..., None] & (self._visit_slots == 0)
            f["vis_state"] = torch.where(first_visit, f["start_state"][..., None], f["vis_state"])
            f["vis_steps"] = f["vis_steps"].masked_fill(first_visit, 0)
            f["vis_time"] = f["vis_time"].masked_fill(first_visit, 0.0)
            f["vis_internal"] = f["vis_internal"].masked_fill(first_visit, 0.0)
        if g.memory_nodes:  # a new invocation remembers where it started
            started = torch.zeros(self.batch_size, g.n_nodes, device=self.device)
            started = started.scatter_add(1, node, invoked.float()) > 0
            f["memory"] = torch.where(started[..., None], g.remember_all(ctx.obs), f["memory"])
        self.invoked = invoked  # (counted in the statistics at the next observe)

    # ------------------------------------------------------------------ observing
    def observe(
        self, step_td: TensorDict, ctx: StepContext, transitions: bool = True
    ) -> TensorDict | None:
        """Account one env step, pop what ended and return the finished SMDP transitions.

        With ``transitions=False`` (greedy evaluation, no learning) nothing is returned.
        """
        g, f = self.graph, dict(self._fields)
        step = entries(step_td)
        # multi-agent rows (``hrl_torch.multiagent``): an agent that does not act at this step
        # is in the middle of its primitive action; its stack waits untouched
        self._acting = step.get("acting", None)
        step, bad = self._bad_steps(step, f)  # rows whose step is skipped, or None
        is_init, term, trunc = step["is_init"], step["terminated"], step["truncated"]
        real = ~is_init
        stepped = real if self._acting is None else real & self._acting
        inst, node = f["inst"], f["node"]
        active = (inst >= 0) & stepped[:, None]
        is_prim = torch.take(g.node_is_primitive, node) & active
        self._accumulate(f, active, node, step["reward"], step["duration"], ctx)

        # which levels end: own termination (primitives always), episode end, guard
        own = ctx.terminated.gather(1, node) & active
        env_ended = active & term[:, None]
        ended_own = own | is_prim | env_ended
        cut = ended_own | (active & trunc[:, None])  # truncation cuts, not terminal
        timeout = self._timeouts(f, active, is_prim, node)
        if timeout is not None:
            cut = cut | timeout
        if bad is not None:  # a skipped step aborts the row's whole stack
            cut = cut | (active & bad[:, None])
        if self.interrupt is not None:  # e.g. the tau_any scheme (hrl_torch.multiagent)
            cut = cut | (self.interrupt(cut.cummax(1).values & active, ended_own) & active)
        popped = cut.cummax(1).values & active  # a subtask that ends aborts what it called
        chose = active & ~is_prim  # levels whose child ran this step
        child_ended = popped.roll(-1, 1)  # (the last level never chooses: no wrap-around)
        emit = chose & child_ended
        taught = stepped  # rows whose primitive step is a transition
        if bad is not None:  # ... and teaches nothing
            emit, taught = emit & ~bad[:, None], stepped & ~bad
        terminal = (own | env_ended) & chose
        ran = is_prim if bad is None else is_prim & ~bad[:, None]  # the primitive, if it teaches

        batch = None
        if transitions:
            child_done = ended_own.roll(-1, 1) & emit
            batch = self._transitions(f, step, ctx, emit, child_done, terminal, trunc, taught, ran)
        if self.config.record_visited:
            self._record_visits(f, chose & ~child_ended, ctx, node)

        if self.count_stats:
            self.stats.count(node, self.invoked, popped, ended_own, f["inv_steps"])
        f["inst"] = inst.masked_fill(popped, -1)
        f["top"] = (f["top"] - popped.sum(1)).masked_fill(is_init, -1)
        f["done"] = (term | trunc) & real
        self._replace(f)
        return batch

    def _bad_steps(self, step: dict, f: dict):
        """Rewards must be finite and durations finite and >= 0 (else tables fill with inf/NaN).

        A bad step raises ``BadStepError`` naming the row and the primitive that ran, or (with
        ``on_bad_step="skip"``) is counted: returns ``(step, bad [B])`` with a copy of the
        step's fields ``step`` whose bad rows have reward and duration 0; ``(step, None)`` if no
        step is bad.
        """
        reward, tau = step["reward"], step["duration"]
        check = (reward + tau) * 0 + tau  # NaN for inf/NaN in either, < 0 for d < 0
        if check.numel() == 0 or check.amin().tolist() >= 0:  # (False for a NaN amin)
            return step, None
        ok = check >= 0
        bad = ~ok & ~step["is_init"]
        row = int((~ok).nonzero()[0])
        if self.config.on_bad_step == "raise":
            top = int(f["top"][row])
            inst = int(f["inst"][row, top]) if top >= 0 else -1
            ran = f" while {self.graph.instance_path(inst)!r} ran" if inst >= 0 else ""
            raise BadStepError(
                f"env row {row} returned reward {float(reward[row])} and duration "
                f"{float(tau[row])}{ran}: rewards must be finite, durations finite and >= 0 "
                "(ExecutorConfig(on_bad_step='skip') skips such steps and counts them)"
            )
        self.skipped_steps.index_add_(0, self.learner, bad.float())
        zero = torch.zeros((), device=reward.device)
        step = dict(step)
        step["reward"] = torch.where(ok, reward, zero)
        step["duration"] = torch.where(ok, tau, zero)
        return step, bad

    def _accumulate(self, f: dict, active, node, reward, tau, ctx: StepContext) -> None:
        """Add the step's reward and time to the current child of every active level."""
        g = self.graph
        r = active * reward[:, None]
        f["reward"] = f["reward"] + r
        if self.gamma == 1.0:  # undiscounted: the same sums
            f["disc_reward"] = f["reward"]
        else:
            f["disc_reward"] = f["disc_reward"] + discount(self.gamma, f["time"]) * r
        if g.shaping_nodes and self._obs is not None:
            shaping = g.shaping_rewards(self._obs, self._action, ctx.obs, f["memory"])
            f["internal"] = f["internal"] + active * discount(self.gamma, f["time"]) * (
                shaping.gather(1, node)
            )
        f["steps"] = f["steps"] + active
        f["time"] = f["time"] + active * tau[:, None]
        f["inv_steps"] = f["inv_steps"] + active

    def _timeouts(self, f: dict, active, is_prim, node) -> torch.Tensor | None:
        """Levels ``[B, D]`` past the guard, or ``None`` (raises with ``on_timeout="raise"``).

        The guard spares the root: a continuing root never terminates by design.
        """
        cfg = self.config
        # an invocation's steps grow by at most one per step: after seeing the longest at m,
        # none can reach the guard for max - m - 1 steps (stale levels counted too)
        if self._guard_quiet > 0:
            self._guard_quiet -= 1
            return None
        longest = f["inv_steps"][:, 1:].amax().tolist() if self.depth > 1 else 0
        if longest < cfg.max_subtask_steps:
            self._guard_quiet = cfg.max_subtask_steps - longest - 1
            return None
        timeout = active & ~is_prim & (self.levels > 0) & (f["inv_steps"] >= cfg.max_subtask_steps)
        if cfg.on_timeout == "raise" and bool(timeout.any()):
            row, lvl = (int(v) for v in timeout.nonzero()[0])
            name = self.graph.names[int(node[row, lvl])]
            path = self.graph.instance_path(int(f["inst"][row, lvl]))
            raise SubtaskTimeoutError(
                f"subtask {name!r} ran {cfg.max_subtask_steps} primitive steps without "
                f"terminating (env row {row}, instance {path})"
            )
        return timeout

    def _record_visits(self, f: dict, continuing, ctx: StepContext, node) -> None:
        """Append ``s'`` to the visit buffer of the levels whose child goes on.

        ``s'`` is abstracted for each level's node; visit ``k`` of a child lives in slot
        ``k % L``.
        """
        size = self.config.record_visited
        slot = (f["steps"] % size).unsqueeze(-1)  # steps already counts this step: visit index
        here = continuing[..., None] & (self._visit_slots == slot)
        state = ctx.abstract.gather(1, node)
        for key, value in (
            ("vis_state", state),
            ("vis_steps", f["steps"]),
            ("vis_time", f["time"]),
            ("vis_internal", f["internal"]),
        ):
            f[key] = torch.where(here, value[..., None].to(f[key].dtype), f[key])

    def _transitions(self, f, step, ctx, emit, child_done, terminal, trunc, real, ran):
        """The finished SMDP transitions of this step (see the module docstring)."""
        g, b, node = self.graph, self.batch_size, f["node"]
        if g.internal_nodes:
            pseudo = g.internal_rewards_at_termination(ctx.obs, f["memory"]).gather(1, node)
            pseudo = pseudo * terminal
        else:
            pseudo = self._no_reward
        level = {
            "valid": emit,
            "inst": f["inst"],
            "node": node,
            "child": f["child"],
            "state": f["start_state"],
            "steps": f["steps"],
            "duration": f["time"],
            "reward": f["reward"],
            "discounted_reward": f["disc_reward"],
            "internal_reward": f["internal"],
            "pseudo_reward": pseudo,
            "terminal": terminal,
            "child_done": child_done,
            "ran": ran,
        }
        uses = self.uses
        if "parent_inst" in uses:
            level["parent_inst"] = _shift_right(f["inst"], fill=-1)
        if "next_state" in uses:
            level["next_state"] = ctx.abstract.gather(1, node)
        if "truncated" in uses:
            level["truncated"] = trunc[:, None] & emit & ~terminal  # (a termination: terminal)
        if "greedy" in uses:
            level["greedy"], level["own_greedy"] = f["greedy"], f["own_greedy"]
        if ctx.features is not None:
            level["features"] = f["start_features"]
            level["next_features"] = ctx.features.gather(
                1, node[..., None].expand(-1, -1, ctx.features.shape[2])
            )
        if self.score_width:
            level["score_index"] = f["score_index"]
            level["score_value"] = f["score_value"]
        if self.config.record_visited:
            level.update(
                visited_state=f["vis_state"],
                visited_steps=f["vis_steps"],
                visited_time=f["vis_time"],
                visited_internal=f["vis_internal"],
                visited_valid=self._visit_slots
                < f["steps"].clamp_max(self.config.record_visited)[..., None],
            )
        size = torch.Size([b])
        return TensorDict._new_unsafe(
            {
                "learner": self.learner,
                LEVEL: TensorDict._new_unsafe(level, batch_size=torch.Size([b, self.depth])),
                PRIMITIVE: TensorDict._new_unsafe(self._primitive(f, step, real, ran), size),
            },
            batch_size=size,
        )

    def _primitive(self, f: dict, step: dict, real, ran) -> dict:
        """The fields of the primitive step each row just took (``batch[PRIMITIVE]``).

        ``ran [B, D]`` marks the level of the primitive (its ``state`` reads 0 where the step
        teaches nothing). Only ``reward`` and ``duration`` unless ``"primitive"`` is used.
        """
        out = {"reward": step["reward"], "duration": step["duration"]}
        if "primitive" not in self.uses:
            return out
        g, top = self.graph, f["top"]
        top1 = f["inst"].amax(1) + 1  # the instance on top, + 1
        out.update(
            valid=real & (top >= 0),
            inst=top1 - 1,
            node=torch.take(g.inst_node_1, top1),
            state=(f["start_state"] * ran).sum(1),
            action=f["cont_action"] if g.action_dim else torch.take(g.inst_action_1, top1),
        )
        if "greedy" in self.uses:
            out["greedy"] = f["own_greedy"].all(1)  # the levels at and above the top hold True
        return out

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        """The Task-Stacks and the last action and observation, for exact resume."""
        return {
            "stack": self.stack.state_dict(),
            "stats": self.stats.state_dict(),
            "action": self._action.clone(),
            "obs": {} if self._obs is None else self._obs.to_dict(),
            "skipped_steps": self.skipped_steps.clone(),
            "invoked": self.invoked.clone(),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict`` taken from an executor of the same shape."""
        fields = dict(state["stack"])
        if "node" not in fields and "inst" in fields:  # a checkpoint from before the field
            fields["node"] = self.graph.path_node_1[fields["inst"].amax(1).to(self.device) + 1]
        stack = self.stack.load_state_dict(fields)
        self.stats.load_state_dict(state["stats"])
        self.stack = stack
        self._action = state["action"].to(self.device).clone()
        skipped = state.get("skipped_steps", torch.zeros_like(self.skipped_steps))
        self.skipped_steps = skipped.to(self.device).clone()
        invoked = state.get("invoked", torch.zeros_like(self.invoked))  # (older checkpoints)
        self.invoked = invoked.to(self.device).clone()
        obs = state["obs"]
        self._obs = TensorDict(obs, batch_size=[self.batch_size]) if obs else None


def _memory_feature_depth(graph: TaskGraph) -> int:
    """The deepest level where a node with invocation memory and features runs (-1: none)."""
    device = graph.inst_node.device
    nodes = torch.tensor(graph.memory_feature_nodes, dtype=torch.long, device=device)
    memory_inst = torch.isin(graph.inst_node, nodes)
    return int(graph.inst_depth[memory_inst].max()) if memory_inst.any() else -1


def _level_spans(depth: int, depth_1: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The levels' roles in a push, by old and new top: ``(spans, code)``.

    ``spans[(old + 1) * (D + 1) + new + 1]`` is ``[4, D]``: the levels kept (below the old
    top), the ones that chose a child (old top .. new top - 1), the new invocations (above
    the old top up to the new one) and the fresh ones (either). ``code[top1]`` is
    ``depth + 1 + (D + 1)`` of the instance ``top1 - 1``, so that ``old * (D + 1) + code``
    is the row of ``spans``.
    """
    lv = torch.arange(depth)
    rows = []
    for old in range(-1, depth):
        for new in range(-1, depth):
            kept = lv < old
            chose = ~kept & (lv < new)
            invoked = (lv > old) & (lv <= new)
            rows.append(torch.stack([kept, chose, invoked, chose | invoked]))
    code = depth_1 + 1 + (depth + 1)
    return torch.stack(rows).to(depth_1.device), code


def _as_choice(out) -> Choice:
    """A policy's ``select`` result as a ``Choice`` (tuples ``(child, greedy[, action])``)."""
    if isinstance(out, Choice):
        return out
    return Choice(out[0], out[1], out[2] if len(out) > 2 else None)


def _raise_stuck(g: TaskGraph, stuck: torch.Tensor, node: torch.Tensor) -> None:
    """A subtask that must choose but has no available child is a graph error."""
    row, level = (int(v) for v in stuck.nonzero()[0])
    raise GraphError(
        f"subtask {g.names[int(node[row, level])]!r} has no available child in env row {row} "
        f"(every child is terminated, not initiable or masked)"
    )


def _shift_left(x: torch.Tensor) -> torch.Tensor:
    """``out[:, k] = x[:, k + 1]``; the last column gets 0 (False)."""
    return torch.nn.functional.pad(x[:, 1:], (0, 1))


def _shift_right(x: torch.Tensor, fill=0) -> torch.Tensor:
    """``out[:, k] = x[:, k - 1]``; the first column gets ``fill``."""
    return torch.nn.functional.pad(x[:, :-1], (1, 0), value=fill)


class ExecutorStats:
    """Per learner and node: calls, finished invocations, successes and their lengths.

    One buffer ``[4, P * N]`` (rows: calls, ends, successes, durations), so a step counts
    with one ``index_add_``; ``calls`` etc. are views of its rows ``[P, N]``.

    Args:
        learner: the learner of each executor row ``[B]``.
        n_learners: ``P``.
        n_nodes: ``N``.
    """

    FIELDS = ("calls", "ends", "successes", "durations")

    def __init__(self, learner: torch.Tensor, n_learners: int, n_nodes: int) -> None:
        self.counts = torch.zeros(4, n_learners * n_nodes, device=learner.device)
        self.shape = (n_learners, n_nodes)
        self._by_field = self.counts.view(4, n_learners, n_nodes)  # (a view: counts move)
        self._at = (torch.arange(4, device=learner.device)[:, None, None], learner[:, None])
        for k, name in enumerate(self.FIELDS):
            setattr(self, name, self.counts[k].view(self.shape))

    def count(self, node, invoked, popped, ended_own, inv_steps) -> None:
        """Count calls, finished invocations, successes and lengths in steps.

        ``[B, D]`` masks of the stack before this step's pops: ``invoked`` the invocations the
        last ``act`` started, ``popped`` the finished ones (``ended_own``: on their own).
        """
        values = torch.stack([invoked, popped, ended_own & popped, inv_steps * popped]).float()
        add_at(self._by_field, (*self._at, node), values)

    def reset(self) -> None:
        """Zero every counter (after logging)."""
        self.counts.zero_()

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The counters since the last log (a resumed run logs what it would have)."""
        return {k: getattr(self, k).clone() for k in self.FIELDS}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore ``state_dict``."""
        for k, v in state.items():
            getattr(self, k).copy_(v)
