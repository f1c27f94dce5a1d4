"""The batched Task-Stack executor (Section 3.2).

For every env row the executor keeps a Task-Stack of ``D`` levels (``execution.stack``): the
instance at each level, the child it chose, the abstract state where that child started and the
reward and time accumulated since. ``observe`` takes one env step: it accumulates rewards, pops
every level that ended (a terminating subtask aborts everything it called) and emits the
finished SMDP transitions as a TensorDict. ``act`` pushes children until a primitive is on top
and returns the primitive actions. The executor never updates values, and never writes into a
stack: each call replaces ``self.stack`` by a new one.

The transitions (a TensorDict ``[B]`` with ``learner``, ``batch[LEVEL] [B, D]`` and
``batch[PRIMITIVE] [B]``) are declared key by key, with shapes and dtypes, in
``execution.transitions`` (``LEVEL_KEYS``, ``PRIMITIVE_KEYS``); some keys are computed only when
the executor's ``uses`` asks for them (``OPTIONAL``; a learner names the ones it reads in
``Learner.uses``). ``Choice``, ``Policy`` and the policies' optional capabilities live there too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
from tensordict import TensorDict

from hrl_torch.common.ops import add_at, below, discount, entries, row_layout
from hrl_torch.execution.descent import Descent, level_spans
from hrl_torch.execution.stack import TaskStack
from hrl_torch.execution.transitions import (  # noqa: F401  (LEVEL, PRIMITIVE, Choice, Policy: re-exported)
    LEVEL,
    OPTIONAL,
    PRIMITIVE,
    Choice,
    ChoosesAll,
    Policy,
    SelectsRows,
    TransitionWriter,
    as_choice,
    is_kind,
)
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError


class SubtaskTimeoutError(RuntimeError):
    """A subtask ran more primitive steps than ``ExecutorConfig.max_subtask_steps``."""


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


def bad_step_error(graph, row: int, reward, tau, top, inst) -> BadStepError:
    """The error for env row ``row``'s non-finite reward or bad duration (``[B]`` / stacks)."""
    level = int(top[row])
    node = int(inst[row, level]) if level >= 0 else -1
    ran = f" while {graph.instance_path(node)!r} ran" if node >= 0 else ""
    return BadStepError(
        f"env row {row} returned reward {float(reward[row])} and duration "
        f"{float(tau[row])}{ran}: rewards must be finite, durations finite and >= 0 "
        "(ExecutorConfig(on_bad_step='skip') skips such steps and counts them)"
    )


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
        sums: keep each level's child, start state and reward, time and step sums (what
            transitions carry; off for agents that emit none, e.g. greedy evaluation: 12 ops
            per step fewer).
    """

    #: transition keys computed only when asked for (``hrl_torch.execution.transitions.OPTIONAL``)
    OPTIONAL = OPTIONAL
    #: the bad-step and stuck checks when deferred (``hrl_torch.training.deferred.defer_checks``)
    deferred_bad = deferred_stuck = deferred_timeout = None
    static_guard = False  #: the guard every step, no read (``hrl_torch.training.cuda_graph``)

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
        sums: bool = True,
    ) -> None:
        self.uses = self._checked_uses(uses)
        self.graph = graph
        self.config = config or ExecutorConfig()
        self.gamma = float(gamma)
        self.batch_size = batch_size
        device = graph.node_children.device
        self.device = device
        long = dict(dtype=torch.long, device=device)
        if learner is None:  # (made on the CPU: n_learners is read before the move)
            learner = torch.arange(batch_size) // (envs_per_learner or batch_size)
        # read where the caller made it (the CPU: ``meta`` and CUDA rows need no host read)
        self.n_learners = int(learner.max()) + 1 if batch_size else 0
        self.learner = learner.to(device)
        # (read on the CPU: the agent tells the learner, which then needs no device read)
        self.row_layout = row_layout(learner, device)
        self.envs_per_learner = envs_per_learner or batch_size
        self.depth = graph.max_levels
        self.levels = torch.arange(self.depth, **long)
        self.rows = torch.arange(batch_size, **long)
        self.score_width = score_width
        self.guard_quiet = 0  # steps during which no invocation can reach the guard
        self.stack = TaskStack.empty(
            graph, batch_size, max(self.config.record_visited, 1), score_width
        )
        self.descent = Descent(graph, batch_size, score_width)
        self.writer = TransitionWriter(self)
        # the per-level sums a new child restarts (the discounted sums are the plain ones when
        # gamma is 1; the internal ones stay 0 without shaping rewards)
        self.sums = sums or self.config.record_visited  # (visits read the sums too)
        self._accumulators = ["steps", "time", "reward"] if self.sums else []
        if self.gamma != 1.0 and self.sums:
            self._accumulators.append("disc_reward")
        if graph.shaping_nodes and self.sums:
            self._accumulators.append("internal")
        self._spans, self._span_code_1 = level_spans(self.depth, graph.inst_depth_1)
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

    def transition_sizes(self) -> dict[str, int]:
        """The dims of this executor's transitions (``transitions.check_transitions``)."""
        g = self.graph
        return {
            "B": self.batch_size,
            "D": self.depth,
            "L": self.config.record_visited,
            "F": g.max_features,
            "K": self.score_width,
            "A": g.action_dim,
        }

    @property
    def acting(self) -> torch.Tensor | None:
        """The agent rows acting at the current step ``[B]`` (``None``: every row acts)."""
        return self._acting

    def rewind(self, fields: dict[str, torch.Tensor], acting: torch.Tensor) -> None:
        """Put the stacks back to ``fields``; only the ``acting`` rows act at the next ``act``.

        ``fields``: ``stack.tensors()`` of an earlier moment (agents that choose again in one
        step: ``hrl_torch.multiagent.broadcast.choose_in_order``).
        """
        self._replace(fields)
        self._acting = acting

    def continue_rows(self, other: HierarchicalExecutor, rows: torch.Tensor) -> None:
        """Take over the rows ``rows`` of ``other`` in their current state (this has ``len(rows)``).

        Their Task-Stacks, last actions and observations and the latest invocations carry over,
        so each row goes on exactly as in ``other`` (``HierarchicalAgent.subset``).
        """
        self.stack = other.stack[rows]
        self._action = other._action[rows]
        self._obs = None if other._obs is None else other._obs[rows]
        self.invoked = other.invoked[rows]

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
        self.guard_quiet = 0  # stacks from elsewhere: check the guard at the next step

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
        self.guard_quiet = self.config.max_subtask_steps - 1  # (no invocation has run yet)

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
            # rows whose stack ends above a level where one can start (all rows: static shapes)
            low = (f["top"] < self._memory_depth)[:, None, None]
            new_features = torch.where(low, g.start_features(ctx.obs, ctx.features), ctx.features)
        choice = policy.choose_all(ctx, step) if is_kind(policy, ChoosesAll) else None
        greedy = "greedy" in self.uses  # (the greedy flags: kept only when used)
        if choice is not None:
            top1, own_greedy = self.descent.follow(self._start_code(f), choice, greedy)
        else:
            rows = float("inf") if self.static_guard else self.COMPACT_ROWS  # (static: all rows)
            top1, own_greedy = self.descent.level_by_level(
                f, self._start_code(f), ctx, policy, step, new_features, rows, greedy
            )
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
        """Where each row's descent starts ``[B]`` (a descent code, ``compile_paths``).

        The instance on top (the root for an empty stack); nothing for a row waiting for its
        reset and for an agent row that does not act (its primitive stays on top).
        """
        g = self.graph
        top = f["inst"].amax(1)  # ids grow along a path: the top is the largest (-1: none)
        code = torch.take(g.inst_start_code, top).masked_fill(f["done"], g.n_choosers)
        if self._acting is not None:
            code = torch.where(self._acting, code, g.n_choosers + 1 + top)
        return code

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
        kept, chose, invoked, fresh = self._spans.index_select(1, span).unbind(0)
        f["inst"] = g.path_inst_1.index_select(0, top1)
        f["node"] = node = g.path_node_1.index_select(0, top1)
        f["top"] = torch.take(g.inst_depth_1, top1)
        if not g.never_stuck:
            stuck = chose & ~ctx.available.any(-1).gather(1, node)
            if self.deferred_stuck is not None:  # (hrl_torch.training.deferred: no read)
                self.deferred_stuck.record(stuck.any(1), stuck=stuck, node=node)
            elif stuck.any().tolist():
                _raise_stuck(g, stuck, node)
        if own_greedy is not None:
            f["own_greedy"] = own = torch.where(kept, f["own_greedy"], own_greedy)
            f["greedy"] = own.cummin(1).values  # the level's own choice and every ancestor's
        if self.sums:  # (the child and the start state: read by transitions only)
            f["child"] = torch.where(kept, f["child"], g.path_child_1.index_select(0, top1))
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
            first_visit = chose[..., None] & (self.writer.visit_slots == 0)
            f["vis_state"] = torch.where(first_visit, f["start_state"][..., None], f["vis_state"])
            f["vis_steps"] = f["vis_steps"].masked_fill(first_visit, 0)
            f["vis_time"] = f["vis_time"].masked_fill(first_visit, 0.0)
            f["vis_internal"] = f["vis_internal"].masked_fill(first_visit, 0.0)
        if g.memory_nodes:  # a new invocation remembers where it started
            started = torch.zeros(self.batch_size, g.n_nodes, device=self.device)
            started = started.scatter_add(1, node, invoked.float()) > 0
            f["memory"] = torch.where(started[..., None], g.remember_all(ctx.obs), f["memory"])
        self.invoked = invoked  # (counted in the statistics at the next observe)

    #: from this many rows on (CPU), the level-by-level choices are made for the rows that
    #: choose at the level only (``policy.select_rows``)
    COMPACT_ROWS = 1024

    # ------------------------------------------------------------------ observing
    def observe(
        self, step_td: TensorDict, ctx: StepContext, transitions: bool = True
    ) -> TensorDict | None:
        """Account one env step, pop what ended and return the finished SMDP transitions.

        With ``transitions=False`` (greedy evaluation, no learning) nothing is returned.
        """
        g, f = self.graph, dict(self._fields)
        step = entries(step_td)
        # multi-agent rows (``hrl_torch.multiagent.cooperative``): an agent that does not act at
        # this step is in the middle of its primitive action; its stack waits untouched
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
        if self.interrupt is not None:  # e.g. the tau_any scheme (hrl_torch.multiagent.cooperative)
            cut = cut | (self.interrupt(below(cut) & active, ended_own) & active)
        popped = below(cut) & active  # a subtask that ends aborts what it called
        batch = None
        if transitions or self.config.record_visited:  # (nothing else reads these masks)
            chose = active & ~is_prim  # levels whose child ran this step
            child_ended = popped.roll(-1, 1)  # (the last level never chooses: no wrap-around)
            if transitions:
                ends = (own | env_ended, ended_own)
                batch = _emit(self, f, step, ctx, chose, child_ended, ends, is_prim, stepped, bad)
            if self.config.record_visited:
                self.writer.record_visits(f, chose & ~child_ended, ctx, node)

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
        if self.deferred_bad is not None and self.config.on_bad_step == "raise":
            bad = ~(check >= 0)  # (hrl_torch.training.deferred: no read)
            self.deferred_bad.record(bad, reward=reward, tau=tau, top=f["top"], inst=f["inst"])
            return step, None
        if check.numel() == 0 or check.amin().tolist() >= 0:  # (False for a NaN amin)
            return step, None
        ok = check >= 0
        bad = ~ok & ~step["is_init"]
        row = int((~ok).nonzero()[0])
        if self.config.on_bad_step == "raise":
            raise bad_step_error(self.graph, row, reward, tau, f["top"], f["inst"])
        self.skipped_steps.index_add_(0, self.learner, bad.float())
        zero = torch.zeros((), device=reward.device)
        step = dict(step)
        step["reward"] = torch.where(ok, reward, zero)
        step["duration"] = torch.where(ok, tau, zero)
        return step, bad

    def _accumulate(self, f: dict, active, node, reward, tau, ctx: StepContext) -> None:
        """Add the step's reward and time to the current child of every active level."""
        g = self.graph
        f["inv_steps"] = f["inv_steps"] + active
        if not self.sums:  # (no transitions read them)
            return
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

    def _timeouts(self, f: dict, active, is_prim, node) -> torch.Tensor | None:
        """Levels ``[B, D]`` past the guard, or ``None`` (raises with ``on_timeout="raise"``).

        The guard spares the root: a continuing root never terminates by design.
        """
        cfg = self.config
        # an invocation's steps grow by at most one per step: after seeing the longest at m,
        # none can reach the guard for max - m - 1 steps (stale levels counted too)
        if self.guard_quiet > 0 and not self.static_guard:
            self.guard_quiet -= 1
            return None
        limit = cfg.max_subtask_steps  # (below: the deferred check, or the static mask)
        over = active & ~is_prim & (self.levels > 0) & (f["inv_steps"] >= limit)
        if self.deferred_timeout is not None and cfg.on_timeout == "raise":  # (no read)
            self.deferred_timeout.record(over.any(1), over=over, node=node, inst=f["inst"])
            return None
        if self.static_guard and cfg.on_timeout != "raise":  # (the mask every step, no read)
            return over
        longest = f["inv_steps"][:, 1:].amax().tolist() if self.depth > 1 else 0
        if longest < limit:
            self.guard_quiet = limit - longest - 1
            return None
        if cfg.on_timeout == "raise" and bool(over.any()):
            row, lvl = (int(v) for v in over.nonzero()[0])
            name = self.graph.names[int(node[row, lvl])]
            path = self.graph.instance_path(int(f["inst"][row, lvl]))
            raise SubtaskTimeoutError(
                f"subtask {name!r} ran {cfg.max_subtask_steps} primitive steps without "
                f"terminating (env row {row}, instance {path})"
            )
        return over

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


def _emit(executor, f: dict, step: dict, ctx, chose, child_ended, ends, is_prim, stepped, bad):
    """``HierarchicalExecutor.observe``'s finished transitions (``TransitionWriter.emit``).

    ``ends``: the levels that terminated or saw the episode end, and ``ended_own``.
    """
    if not executor.sums:
        raise ValueError("an executor without sums (sums=False) emits no transitions")
    emit = chose & child_ended
    taught = stepped  # rows whose primitive step is a transition
    if bad is not None:  # ... and teaches nothing
        emit, taught = emit & ~bad[:, None], stepped & ~bad
    ran = is_prim if bad is None else is_prim & ~bad[:, None]  # the primitive, if it teaches
    child_done = ends[1].roll(-1, 1) & emit
    return executor.writer.emit(
        f, step, ctx, emit, child_done, ends[0] & chose, step["truncated"], taught, ran
    )


def _memory_feature_depth(graph: TaskGraph) -> int:
    """The deepest level where a node with invocation memory and features runs (-1: none)."""
    nodes = torch.tensor(graph.memory_feature_nodes, dtype=torch.long)
    memory_inst = torch.isin(graph.host("inst_node"), nodes)  # (on the CPU)
    return int(graph.host("inst_depth")[memory_inst].max()) if memory_inst.any() else -1


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
        return {k: self._by_field[i].clone() for i, k in enumerate(self.FIELDS)}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore ``state_dict``."""
        for k, v in state.items():
            self._by_field[self.FIELDS.index(k)].copy_(v)
