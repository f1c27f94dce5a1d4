"""The batched Task-Stack executor (Section 3.2).

For every env row the executor keeps a Task-Stack of ``D`` levels as tensors ``[B, D]``: the
instance at each level, the child it chose, the abstract state where that child started and the
reward and time accumulated since. ``observe`` takes one env step: it accumulates rewards, pops
every level that ended (a terminating subtask aborts everything it called) and emits the
finished SMDP transitions as a TensorDict. ``act`` pushes children until a primitive is on top
and returns the primitive actions. The executor never updates values.

Transitions are a TensorDict ``[B]`` with ``learner [B]`` (learner of the row) and two nested
TensorDicts (their keys are the constants ``LEVEL`` and ``PRIMITIVE``):

``batch[LEVEL]`` ``[B, D]``, level ``j`` is the subtask whose child ended:

- ``valid``: a transition was emitted at this level;
- ``inst``, ``node``, ``child`` (slot in the node's children), ``child_inst``, ``parent_inst``;
- ``state`` / ``next_state``: abstract state of ``node`` when the child started / at ``s'``;
- ``steps`` (primitive steps ``N``), ``duration`` (time ``tau``), ``reward`` (external, summed),
  ``discounted_reward`` (sum of ``gamma**t r``), ``internal_reward`` (discounted shaping of
  ``node``), ``pseudo_reward`` (``node``'s pseudo reward if ``s'`` is terminal for it);
- ``terminal`` (``s'`` is terminal for ``node``), ``child_done`` (the child ended by its own
  termination, not by an abort), ``truncated`` (time limit), ``greedy`` (the child and all its
  ancestors were chosen greedily), ``own_greedy`` (the child was chosen greedily);
- with ``record_visited = L > 0``: ``visited_state``, ``visited_steps``, ``visited_time``
  ``[B, D, L]`` and their mask ``visited_valid``: the states of ``node`` during the child, from
  where it started to the step before ``s'`` (all-states updating), the most recent ``L`` kept;
- with feature nodes (``Subtask.features``): ``features`` / ``next_features``
  ``[B, D, F]``, the node's continuous features where the child started / at ``s'``.

``batch[PRIMITIVE]`` ``[B]``, the primitive step just taken: ``valid``, ``inst``, ``node``,
``state``, ``reward``, ``duration``, ``greedy`` (its parent and all ancestors chose greedily),
``action`` (the env action, ``[B, action_dim]`` in continuous action spaces).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

import torch
from tensordict import TensorDict

from hrl_torch.graph import GraphError, StepContext, TaskGraph
from hrl_torch.ops import discount, lookup
from hrl_torch.stack import TaskStack

#: key of the per-level transitions ``[B, D]`` in a transition batch
LEVEL = "level"
#: key of the primitive step ``[B]`` in a transition batch
PRIMITIVE = "primitive"


class SubtaskTimeoutError(RuntimeError):
    """A subtask ran more primitive steps than ``ExecutorConfig.max_subtask_steps``."""


class Policy(Protocol):
    """Chooses children for the instances on top of the stacks."""

    def new_step(self) -> None:
        """Called once at the start of every ``act`` (draw this step's random numbers)."""
        ...

    def select(
        self, inst: torch.Tensor, ctx: StepContext, available: torch.Tensor, step: int, push: int
    ) -> tuple[torch.Tensor, ...]:
        """Return ``(child slot [B], greedy flag [B])`` for instances ``inst [B]``.

        ``push`` counts the pushes made so far in this step. On a graph with continuous
        primitives, return a third tensor ``[B, action_dim]``: the action value of the rows
        whose chosen child is a continuous primitive.
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
    """

    max_subtask_steps: int = 10_000
    on_timeout: Literal["raise", "abort"] = "raise"
    record_visited: int = 0


def _at(x: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
    """``x[b, level[b]]`` for ``x [B, W, ...]`` and ``level [B]`` (clamped to 0)."""
    idx = level.clamp_min(0).view(-1, 1, *([1] * (x.dim() - 2))).expand(-1, 1, *x.shape[2:])
    return x.gather(1, idx).squeeze(1)


def _gather_levels(per_node: torch.Tensor, node: torch.Tensor) -> torch.Tensor:
    """``per_node[b, node[b, k], :]`` for ``per_node [B, N, F]`` and ``node [B, D]``."""
    return per_node.gather(1, node[..., None].expand(-1, -1, per_node.shape[-1]))


def _scatter_at(x: torch.Tensor, slot: torch.Tensor, value) -> None:
    """``x[b, slot[b]] = value[b]`` in place, ``slot [B, 1]``.

    Rows aimed at the trash column write there harmlessly.
    """
    if isinstance(value, torch.Tensor):
        value = value.to(x.dtype).view(x.shape[0], 1, *x.shape[2:])
        idx = slot.view(-1, 1, *([1] * (x.dim() - 2))).expand(-1, 1, *x.shape[2:])
        x.scatter_(1, idx, value)
    else:
        x.scatter_(1, slot.view(-1, 1, *([1] * (x.dim() - 2))).expand(-1, 1, *x.shape[2:]), value)


class HierarchicalExecutor:
    """Task-Stacks for ``B`` env rows over one task graph.

    The stacks are one ``TaskStack`` (``self.stack``) with ``D + 1`` columns: levels
    ``0..D-1`` and a trash column ``D`` that masked writes are aimed at, so a push writes each
    field with one ``scatter_`` and no gather/where.

    Args:
        graph: the task graph.
        batch_size: ``B``.
        envs_per_learner: ``E`` (row ``b`` belongs to learner ``b // E``).
        gamma: discount used for ``discounted_reward`` / ``internal_reward``.
        config: guard and all-states options.
    """

    def __init__(
        self,
        graph: TaskGraph,
        batch_size: int,
        envs_per_learner: int,
        gamma: float = 1.0,
        config: ExecutorConfig | None = None,
    ) -> None:
        self.graph = graph
        self.config = config or ExecutorConfig()
        self.gamma = float(gamma)
        self.batch_size = batch_size
        self.envs_per_learner = envs_per_learner
        self.n_learners = batch_size // envs_per_learner
        device = graph.node_children.device
        self.device = device
        self.depth = graph.max_levels
        long = dict(dtype=torch.long, device=device)
        self.levels = torch.arange(self.depth + 1, **long)
        self.learner = torch.arange(batch_size, **long) // envs_per_learner
        self.rows = torch.arange(batch_size, **long)
        self.stack = TaskStack.empty(graph, batch_size, max(self.config.record_visited, 1))
        self._visit_slots = torch.arange(max(self.config.record_visited, 1), **long)
        self._obs = None
        self._action = torch.zeros(batch_size, **long)
        self.stats = ExecutorStats(self.n_learners, graph.n_nodes, device)

    @property
    def memory(self) -> torch.Tensor:
        """What each node's running invocation remembered ``[B, n_nodes, M]`` (for contexts)."""
        return self.stack.memory

    def reset(self) -> None:
        """Empty every stack (all rows start at the root on the next ``act``)."""
        self.stack.clear()

    # ------------------------------------------------------------------ acting
    def act(self, ctx: StepContext, policy: Policy, step: int) -> torch.Tensor:
        """Push children until a primitive is on top of every live stack; return actions ``[B]``.

        Rows whose stack is empty and whose episode is not over start at the root.
        """
        g, s = self.graph, self.stack
        fresh_memory = g.remember_all(ctx.obs)
        fresh = (s.top < 0) & ~s.done
        self._start_root(fresh, fresh_memory)
        inst = _at(s.inst, s.top).clamp_min(0)
        need = (s.top >= 0) & ~s.done & ~lookup(g.inst_is_primitive, inst)
        policy.new_step()
        push = 0
        while bool(need.any()):
            node = lookup(g.inst_node, inst)
            available = ctx.available.gather(
                1, node.view(-1, 1, 1).expand(-1, 1, ctx.available.shape[2])
            ).squeeze(1)
            _check_available(g, need, available, node)
            choice, greedy, *action = policy.select(inst, ctx, available, step, push)
            push += 1
            self._record_choice(need, node, choice, greedy, ctx)
            inst, need = self._push_child(need, inst, choice, action, ctx, fresh_memory)
        live = s.top >= 0
        if g.action_dim:
            self._action = torch.where(live[:, None], s.cont_action, 0.0)
        else:
            self._action = torch.where(live, lookup(g.node_action, lookup(g.inst_node, inst)), 0)
        self._obs = ctx.obs
        return self._action

    def _start_root(self, fresh: torch.Tensor, fresh_memory: torch.Tensor | None) -> None:
        """Put the root on the empty stacks of the rows ``fresh [B]``."""
        g, s, trash = self.graph, self.stack, self.depth
        slot = torch.where(fresh, 0, trash)[:, None]
        _scatter_at(s.inst, slot, 0)
        _scatter_at(s.inv_steps, slot, 0)
        s.top = torch.where(fresh, 0, s.top)
        if fresh_memory is not None:
            s.memory[:, g.root] = torch.where(
                fresh[:, None], fresh_memory[:, g.root], s.memory[:, g.root]
            )
        self.stats.count_calls(self.learner, g.root, fresh)

    def _record_choice(self, need, node, choice, greedy, ctx: StepContext) -> None:
        """Level ``top`` of the rows ``need`` records its new child and fresh accumulators."""
        s, trash = self.stack, self.depth
        slot = torch.where(need, s.top, trash)[:, None]
        parent_greedy = _at(s.greedy, s.top - 1) | (s.top == 0)
        _scatter_at(s.child, slot, choice)
        _scatter_at(s.start_state, slot, ctx.abstract.gather(1, node[:, None]))
        _scatter_at(s.greedy, slot, greedy & parent_greedy)
        _scatter_at(s.own_greedy, slot, greedy)
        for acc in (s.steps, s.time, s.reward, s.disc_reward, s.internal):
            _scatter_at(acc, slot, 0)
        if ctx.features is not None:
            _scatter_at(s.start_features, slot, _at(ctx.features, node))
        if self.config.record_visited:
            _scatter_at(s.vis_state[:, :, 0], slot, _at(s.start_state, s.top))
            _scatter_at(s.vis_steps[:, :, 0], slot, 0)
            _scatter_at(s.vis_time[:, :, 0], slot, 0.0)

    def _push_child(self, need, inst, choice, action, ctx: StepContext, fresh_memory):
        """Push the chosen children one level up; returns the new tops and who still needs one."""
        g, s, trash = self.graph, self.stack, self.depth
        child_inst = lookup(g.inst_children.view(-1), inst * g.max_children + choice)
        child_inst = child_inst.clamp_min(0)  # rows that push nothing may read padding
        child_node = lookup(g.inst_node, child_inst)
        child_is_prim = lookup(g.node_is_primitive, child_node)
        s.top = s.top + need.long()
        slot = torch.where(need, s.top, trash)[:, None]
        _scatter_at(s.inst, slot, child_inst)
        _scatter_at(s.inv_steps, slot, 0)
        prim_slot = torch.where(need & child_is_prim, s.top, trash)[:, None]
        _scatter_at(s.start_state, prim_slot, ctx.abstract.gather(1, child_node[:, None]))
        if g.action_dim:
            if not action or action[0] is None:
                raise GraphError("a continuous primitive was chosen without an action value")
            pushed = (need & child_is_prim)[:, None]
            s.cont_action = torch.where(pushed, action[0], s.cont_action)
        if fresh_memory is not None:
            s.memory[self.rows, child_node] = torch.where(
                need[:, None], fresh_memory[self.rows, child_node], s.memory[self.rows, child_node]
            )
        self.stats.count_calls(self.learner, child_node, need)
        return torch.where(need, child_inst, inst), need & ~child_is_prim

    # ------------------------------------------------------------------ observing
    def observe(
        self, step_td: TensorDict, ctx: StepContext, transitions: bool = True
    ) -> TensorDict | None:
        """Account one env step, pop what ended and return the finished SMDP transitions.

        With ``transitions=False`` (greedy evaluation, no learning) nothing is returned.
        """
        g, s = self.graph, self.stack
        reward = step_td["reward"]
        _check_step(reward, step_td["duration"])
        real = ~step_td["is_init"]
        env_term = step_td["terminated"] & real
        env_trunc = step_td["truncated"] & real & ~env_term
        active = (self.levels[None, :] <= s.top[:, None]) & real[:, None]
        node = lookup(g.inst_node, s.inst.clamp_min(0))
        is_prim = lookup(g.node_is_primitive, node) & active
        self._accumulate(active, node, reward, step_td["duration"], ctx)

        # which levels end: own termination (primitives always), episode end, guard
        own = ctx.terminated.gather(1, node) & active
        ended_own = own | is_prim | (active & env_term[:, None])
        timeout = self._timeouts(active, is_prim, node)
        cut = ended_own | timeout | (active & env_trunc[:, None])
        popped = (cut.cumsum(1) > 0) & active  # a subtask that ends aborts what it called
        child_popped = _shift_left(popped)
        emit = active & ~is_prim & child_popped
        child_done = _shift_left(ended_own)
        terminal = (own | env_term[:, None]) & active & ~is_prim

        batch = None
        if transitions:
            batch = self._transitions(
                step_td, ctx, node, emit, child_done, terminal, env_trunc, real
            )
        if self.config.record_visited:
            self._record_visits(active & ~is_prim & ~child_popped, ctx, node)

        # statistics, then pop
        self.stats.count_ends(self.learner, node, popped, ended_own & popped, s.inv_steps)
        s.inst = torch.where(popped, -1, s.inst)
        s.top = torch.where(real, (active & ~popped).sum(1) - 1, -1)
        s.done = env_term | env_trunc
        return batch

    def _accumulate(self, active, node, reward, tau, ctx: StepContext) -> None:
        """Add the step's reward and time to the current child of every active level."""
        g, s = self.graph, self.stack
        s.reward += active * reward[:, None]
        if self.gamma == 1.0:
            s.disc_reward += active * reward[:, None]
        else:
            s.disc_reward += active * discount(self.gamma, s.time) * reward[:, None]
        if g.shaping_nodes and self._obs is not None:
            shaping = g.shaping_rewards(self._obs, self._action, ctx.obs, s.memory)
            s.internal += active * discount(self.gamma, s.time) * shaping.gather(1, node)
        s.steps += active
        s.time += active * tau[:, None]
        s.inv_steps += active

    def _timeouts(self, active, is_prim, node) -> torch.Tensor:
        """Levels ``[B, W]`` past the guard (raises with ``on_timeout="raise"``).

        The guard spares the root: a continuing root never terminates by design.
        """
        cfg, s = self.config, self.stack
        timeout = active & ~is_prim & (self.levels > 0) & (s.inv_steps >= cfg.max_subtask_steps)
        if cfg.on_timeout == "raise" and bool(timeout.any()):
            row, lvl = (int(v) for v in timeout.nonzero()[0])
            name = self.graph.names[int(node[row, lvl])]
            path = self.graph.instance_path(int(s.inst[row, lvl]))
            raise SubtaskTimeoutError(
                f"subtask {name!r} ran {cfg.max_subtask_steps} primitive steps without "
                f"terminating (env row {row}, instance {path})"
            )
        return timeout

    def _record_visits(
        self, continuing: torch.Tensor, ctx: StepContext, node: torch.Tensor
    ) -> None:
        """Append ``s'`` to the visit buffer of the levels whose child goes on.

        ``s'`` is abstracted for each level's node; visit ``k`` of a child lives in slot
        ``k % L``.
        """
        s, size = self.stack, self.config.record_visited
        slot = (s.steps % size).unsqueeze(-1)  # steps already counts this step: visit index
        state = ctx.abstract.gather(1, node)
        for buf, value in ((s.vis_state, state), (s.vis_steps, s.steps), (s.vis_time, s.time)):
            old = buf.gather(2, slot).squeeze(-1)
            buf.scatter_(2, slot, torch.where(continuing, value.to(buf.dtype), old).unsqueeze(-1))

    def _transitions(self, step_td, ctx, node, emit, child_done, terminal, env_trunc, real):
        """The finished SMDP transitions of this step (see the module docstring)."""
        g, s, d = self.graph, self.stack, self.depth
        node, terminal, emit = node[:, :d], terminal[:, :d], emit[:, :d]
        if g.internal_nodes:
            pseudo = g.internal_rewards_at_termination(ctx.obs, s.memory).gather(1, node)
            pseudo = pseudo * terminal
        else:
            pseudo = torch.zeros(node.shape, device=self.device)
        level = {
            "valid": emit,
            "inst": s.inst[:, :d].clone(),
            "node": node,
            "child": s.child[:, :d].clone(),
            "child_inst": _shift_left(s.inst, fill=-1)[:, :d],
            "parent_inst": _shift_right(s.inst, fill=-1)[:, :d],
            "state": s.start_state[:, :d].clone(),
            "next_state": ctx.abstract.gather(1, node),
            "steps": s.steps[:, :d].clone(),
            "duration": s.time[:, :d].clone(),
            "reward": s.reward[:, :d].clone(),
            "discounted_reward": s.disc_reward[:, :d].clone(),
            "internal_reward": s.internal[:, :d].clone(),
            "pseudo_reward": pseudo,
            "terminal": terminal,
            "child_done": child_done[:, :d] & emit,
            "truncated": env_trunc[:, None] & emit & ~terminal,
            "greedy": s.greedy[:, :d].clone(),
            "own_greedy": s.own_greedy[:, :d].clone(),
        }
        if ctx.features is not None:
            level["features"] = s.start_features[:, :d].clone()
            level["next_features"] = _gather_levels(ctx.features, node)
        if self.config.record_visited:
            level.update(
                visited_state=s.vis_state[:, :d].clone(),
                visited_steps=s.vis_steps[:, :d].clone(),
                visited_time=s.vis_time[:, :d].clone(),
                visited_valid=self._visit_slots[None, None, :]
                < s.steps[:, :d].clamp_max(self.config.record_visited)[:, :, None],
            )
        b, dev = self.batch_size, self.device
        return TensorDict(
            {
                "learner": self.learner,
                LEVEL: TensorDict(level, batch_size=[b, d], device=dev),
                PRIMITIVE: TensorDict(self._primitive(step_td, real), batch_size=[b], device=dev),
            },
            batch_size=[b],
            device=dev,
        )

    def _primitive(self, step_td: TensorDict, real: torch.Tensor) -> dict[str, torch.Tensor]:
        """The fields of the primitive step each row just took (``batch[PRIMITIVE]``)."""
        s = self.stack
        inst = _at(s.inst, s.top)
        return {
            "valid": real & (s.top >= 0),
            "inst": inst,
            "node": lookup(self.graph.inst_node, inst.clamp_min(0)),
            "state": _at(s.start_state, s.top),
            "reward": step_td["reward"],
            "duration": step_td["duration"],
            "greedy": _at(s.greedy, s.top - 1),
            "action": self._action.clone(),
        }

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        """The Task-Stacks and the last action and observation, for exact resume."""
        return {
            "stack": self.stack.state_dict(),
            "stats": self.stats.state_dict(),
            "action": self._action.clone(),
            "obs": {} if self._obs is None else self._obs.to_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict`` taken from an executor of the same shape."""
        self.stack.load_state_dict(state["stack"])
        self.stats.load_state_dict(state["stats"])
        self._action = state["action"].to(self.device).clone()
        obs = state["obs"]
        self._obs = TensorDict(obs, batch_size=[self.batch_size]) if obs else None


def _check_step(reward: torch.Tensor, duration: torch.Tensor) -> None:
    """Rewards must be finite and durations finite and >= 0 (else tables fill with inf/NaN)."""
    bad = ~(torch.isfinite(reward) & torch.isfinite(duration) & (duration >= 0))
    if bool(bad.any()):
        row = int(bad.nonzero()[0])
        r, t = float(reward[row]), float(duration[row])
        raise ValueError(
            f"env row {row} returned reward {r} and duration {t}: rewards must be finite, "
            "durations finite and >= 0"
        )


def _check_available(g: TaskGraph, need, available, node) -> None:
    """A subtask that must choose but has no available child is a graph error."""
    stuck = need & ~available.any(-1)
    if bool(stuck.any()):
        row = int(stuck.nonzero()[0])
        raise GraphError(
            f"subtask {g.names[int(node[row])]!r} has no available child in env row {row} "
            f"(every child is terminated, not initiable or masked)"
        )


def _shift_left(x: torch.Tensor, fill=False) -> torch.Tensor:
    """``out[:, k] = x[:, k + 1]``; the last column gets ``fill``."""
    out = torch.full_like(x, fill)
    out[:, :-1] = x[:, 1:]
    return out


def _shift_right(x: torch.Tensor, fill=False) -> torch.Tensor:
    """``out[:, k] = x[:, k - 1]``; the first column gets ``fill``."""
    out = torch.full_like(x, fill)
    out[:, 1:] = x[:, :-1]
    return out


class ExecutorStats:
    """Per learner and node: calls, finished invocations, successes and their lengths."""

    def __init__(self, n_learners: int, n_nodes: int, device: torch.device) -> None:
        shape = (n_learners, n_nodes)
        self.calls = torch.zeros(shape, device=device)
        self.ends = torch.zeros(shape, device=device)
        self.successes = torch.zeros(shape, device=device)
        self.durations = torch.zeros(shape, device=device)
        self.n_nodes = n_nodes

    def count_calls(self, learner: torch.Tensor, node: torch.Tensor, mask: torch.Tensor) -> None:
        """Count one invocation of ``node[b]`` where ``mask[b]``."""
        self.calls.view(-1).index_add_(0, learner * self.n_nodes + node, mask.float())

    def count_ends(self, learner, node, popped, success, inv_steps) -> None:
        """Count finished invocations (``[B, D]`` masks) and their lengths in steps."""
        idx = (learner[:, None] * self.n_nodes + node).reshape(-1)
        self.ends.view(-1).index_add_(0, idx, popped.float().reshape(-1))
        self.successes.view(-1).index_add_(0, idx, success.float().reshape(-1))
        self.durations.view(-1).index_add_(0, idx, (inv_steps * popped).float().reshape(-1))

    def reset(self) -> None:
        """Zero every counter (after logging)."""
        for t in (self.calls, self.ends, self.successes, self.durations):
            t.zero_()

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The counters since the last log (a resumed run logs what it would have)."""
        return {k: getattr(self, k).clone() for k in ("calls", "ends", "successes", "durations")}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore ``state_dict``."""
        for k, v in state.items():
            getattr(self, k).copy_(v)
