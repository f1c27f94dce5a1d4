"""The batched Task-Stack executor (Section 3.2).

For every env row the executor keeps a Task-Stack of ``D`` levels as tensors ``[B, D]``: the
instance at each level, the child it chose, the abstract state where that child started and the
reward and time accumulated since. ``observe`` takes one env step: it accumulates rewards, pops
every level that ended (a terminating subtask aborts everything it called) and emits the
finished SMDP transitions as a TensorDict. ``act`` pushes children until a primitive is on top
and returns the primitive actions. The executor never updates values.

Transition fields (batch ``[B]``; per-level fields ``[B, D]``, level ``j`` is the subtask whose
child ended):

- ``valid``: a transition was emitted at this level; ``learner``: learner of the row ``[B]``;
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
  ``[B, D, F]``, the node's continuous features where the child started / at ``s'``;
- primitive fields ``[B]``: ``prim_valid``, ``prim_inst``, ``prim_node``, ``prim_state``,
  ``prim_reward``, ``prim_duration``, ``prim_greedy``, ``prim_action`` (the env action,
  ``[B, action_dim]`` in continuous action spaces).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

import torch
from tensordict import TensorDict

from hrl_torch.graph import GraphError, StepContext, TaskGraph
from hrl_torch.ops import discount, lookup


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

    Per-level tensors are ``[B, D + 1]``: levels ``0..D-1`` and a trash column ``D`` that masked
    writes are aimed at, so a push writes each field with one ``scatter_`` and no gather/where.

    Args:
        graph: the task graph.
        batch_size: ``B``.
        envs_per_learner: ``E`` (row ``b`` belongs to learner ``b // E``).
        gamma: discount used for ``discounted_reward`` / ``internal_reward``.
        config: guard and all-states options.
    """

    _state_keys = (
        "stack",
        "top",
        "child",
        "start_state",
        "steps",
        "time",
        "reward",
        "disc_reward",
        "internal",
        "greedy",
        "own_greedy",
        "inv_steps",
        "done",
        "vis_state",
        "vis_steps",
        "vis_time",
        "start_features",
        "cont_action",
        "memory",
    )

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
        b, d, n_vis = batch_size, graph.max_levels, max(self.config.record_visited, 1)
        w = d + 1  # + trash column
        self.depth = d
        long = dict(dtype=torch.long, device=device)
        flt = dict(dtype=torch.float32, device=device)
        self.levels = torch.arange(w, **long)
        self.learner = torch.arange(b, **long) // envs_per_learner
        self.rows = torch.arange(b, **long)
        self.stack = torch.full((b, w), -1, **long)
        self.top = torch.full((b,), -1, **long)
        self.child = torch.zeros(b, w, **long)
        self.start_state = torch.zeros(b, w, **long)
        self.steps = torch.zeros(b, w, **long)
        self.time = torch.zeros(b, w, **flt)
        self.reward = torch.zeros(b, w, **flt)
        self.disc_reward = torch.zeros(b, w, **flt)
        self.internal = torch.zeros(b, w, **flt)
        self.greedy = torch.ones(b, w, dtype=torch.bool, device=device)  # with all ancestors
        self.own_greedy = torch.ones(b, w, dtype=torch.bool, device=device)  # this level only
        self.inv_steps = torch.zeros(b, w, **long)
        self.done = torch.zeros(b, dtype=torch.bool, device=device)
        self.vis_state = torch.zeros(b, w, n_vis, **long)
        self.vis_steps = torch.zeros(b, w, n_vis, **long)
        self.vis_time = torch.zeros(b, w, n_vis, **flt)
        # continuous state features where each level's current child started (PG nodes)
        self.start_features = torch.zeros(b, w, max(graph.max_features, 1), **flt)
        # the action vector of the continuous primitive on top (continuous action spaces)
        self.cont_action = torch.zeros(b, max(graph.action_dim, 1), **flt)
        # what the running invocation of each node remembered when it started (memory nodes);
        # pass it to graph.context so their termination and features see it
        self.memory = torch.zeros(b, graph.n_nodes, max(graph.max_memory, 1), **flt)
        self._visit_slots = torch.arange(n_vis, **long)
        self._obs = None
        self._action = torch.zeros(b, **long)
        self.stats = ExecutorStats(self.n_learners, graph.n_nodes, device)

    def reset(self) -> None:
        """Empty every stack (all rows start at the root on the next ``act``)."""
        self.top.fill_(-1)
        self.stack.fill_(-1)
        self.done.zero_()

    # ------------------------------------------------------------------ acting
    def act(self, ctx: StepContext, policy: Policy, step: int) -> torch.Tensor:
        """Push children until a primitive is on top of every live stack; return actions ``[B]``.

        Rows whose stack is empty and whose episode is not over start at the root.
        """
        g, trash = self.graph, self.depth
        fresh_memory = g.remember_all(ctx.obs)
        fresh = (self.top < 0) & ~self.done
        slot = torch.where(fresh, 0, trash)[:, None]
        _scatter_at(self.stack, slot, 0)
        _scatter_at(self.inv_steps, slot, 0)
        self.top = torch.where(fresh, 0, self.top)
        if fresh_memory is not None:
            self.memory[:, g.root] = torch.where(
                fresh[:, None], fresh_memory[:, g.root], self.memory[:, g.root]
            )
        self.stats.count_calls(self.learner, g.root, fresh)
        inst = _at(self.stack, self.top).clamp_min(0)
        need = (self.top >= 0) & ~self.done & ~lookup(g.inst_is_primitive, inst)
        policy.new_step()
        push = 0
        while bool(need.any()):
            node = lookup(g.inst_node, inst)
            available = ctx.available.gather(
                1, node.view(-1, 1, 1).expand(-1, 1, ctx.available.shape[2])
            ).squeeze(1)
            if bool((need & ~available.any(-1)).any()):
                row = int((need & ~available.any(-1)).nonzero()[0])
                raise GraphError(
                    f"subtask {g.names[int(node[row])]!r} has no available child in env row {row} "
                    f"(every child is terminated, not initiable or masked)"
                )
            choice, greedy, *action = policy.select(inst, ctx, available, step, push)
            push += 1
            # level `top` records its new child, where it starts, and fresh accumulators
            slot = torch.where(need, self.top, trash)[:, None]
            parent_greedy = _at(self.greedy, self.top - 1) | (self.top == 0)
            _scatter_at(self.child, slot, choice)
            _scatter_at(self.start_state, slot, ctx.abstract.gather(1, node[:, None]))
            _scatter_at(self.greedy, slot, greedy & parent_greedy)
            _scatter_at(self.own_greedy, slot, greedy)
            for acc in (self.steps, self.time, self.reward, self.disc_reward, self.internal):
                _scatter_at(acc, slot, 0)
            if ctx.features is not None:
                _scatter_at(self.start_features, slot, _at(ctx.features, node))
            if self.config.record_visited:
                _scatter_at(self.vis_state[:, :, 0], slot, _at(self.start_state, self.top))
                _scatter_at(self.vis_steps[:, :, 0], slot, 0)
                _scatter_at(self.vis_time[:, :, 0], slot, 0.0)
            # push the child one level up
            child_inst = lookup(g.inst_children.view(-1), inst * g.max_children + choice)
            child_inst = child_inst.clamp_min(0)  # rows that push nothing may read padding
            child_node = lookup(g.inst_node, child_inst)
            child_is_prim = lookup(g.node_is_primitive, child_node)
            self.top = self.top + need.long()
            slot = torch.where(need, self.top, trash)[:, None]
            _scatter_at(self.stack, slot, child_inst)
            _scatter_at(self.inv_steps, slot, 0)
            prim_slot = torch.where(need & child_is_prim, self.top, trash)[:, None]
            _scatter_at(self.start_state, prim_slot, ctx.abstract.gather(1, child_node[:, None]))
            if g.action_dim:
                if not action or action[0] is None:
                    raise GraphError("a continuous primitive was chosen without an action value")
                pushed = (need & child_is_prim)[:, None]
                self.cont_action = torch.where(pushed, action[0], self.cont_action)
            if fresh_memory is not None:
                self.memory[self.rows, child_node] = torch.where(
                    need[:, None],
                    fresh_memory[self.rows, child_node],
                    self.memory[self.rows, child_node],
                )
            self.stats.count_calls(self.learner, child_node, need)
            inst = torch.where(need, child_inst, inst)
            need = need & ~child_is_prim
        live = self.top >= 0
        if g.action_dim:
            self._action = torch.where(live[:, None], self.cont_action, 0.0)
        else:
            self._action = torch.where(live, lookup(g.node_action, lookup(g.inst_node, inst)), 0)
        self._obs = ctx.obs
        return self._action

    # ------------------------------------------------------------------ observing
    def observe(
        self, step_td: TensorDict, ctx: StepContext, transitions: bool = True
    ) -> TensorDict | None:
        """Account one env step, pop what ended and return the finished SMDP transitions.

        With ``transitions=False`` (greedy evaluation, no learning) nothing is returned.
        """
        g, cfg = self.graph, self.config
        reward = step_td["reward"]
        if bool(torch.isnan(reward).any()):
            row = int(torch.isnan(reward).nonzero()[0])
            raise ValueError(f"the env returned a NaN reward (env row {row})")
        tau = step_td["duration"]
        real = ~step_td["is_init"]
        env_term = step_td["terminated"] & real
        env_trunc = step_td["truncated"] & real & ~env_term
        levels = self.levels[None, :]
        active = (levels <= self.top[:, None]) & real[:, None]
        node = lookup(g.inst_node, self.stack.clamp_min(0))
        is_prim = lookup(g.node_is_primitive, node) & active

        # accumulate reward and time of the current child at every level
        self.reward += active * reward[:, None]
        if self.gamma == 1.0:
            self.disc_reward += active * reward[:, None]
        else:
            disc = discount(self.gamma, self.time)
            self.disc_reward += active * disc * reward[:, None]
        if g.shaping_nodes and self._obs is not None:
            shaping = g.shaping_rewards(self._obs, self._action, ctx.obs, self.memory)
            shaping = shaping.gather(1, node)
            self.internal += active * discount(self.gamma, self.time) * shaping
        self.steps += active
        self.time += active * tau[:, None]
        self.inv_steps += active

        # which levels end: own termination (primitives always), episode end, guard
        own = ctx.terminated.gather(1, node) & active
        ended_own = own | is_prim | (active & env_term[:, None])
        # the guard spares the root: a continuing root never terminates by design
        timeout = active & ~is_prim & (levels > 0) & (self.inv_steps >= cfg.max_subtask_steps)
        if bool(timeout.any()):
            row, lvl = (int(v) for v in timeout.nonzero()[0])
            name = g.names[int(node[row, lvl])]
            if cfg.on_timeout == "raise":
                path = g.instance_path(int(self.stack[row, lvl]))
                raise SubtaskTimeoutError(
                    f"subtask {name!r} ran {cfg.max_subtask_steps} primitive steps without "
                    f"terminating (env row {row}, instance {path})"
                )
        cut = ended_own | timeout | (active & env_trunc[:, None])
        popped = (cut.cumsum(1) > 0) & active
        child_popped = _shift_left(popped)
        emit = active & ~is_prim & child_popped
        child_done = _shift_left(ended_own)
        terminal = (own | env_term[:, None]) & active & ~is_prim

        batch = None
        if transitions:
            batch = self._transitions(
                step_td, ctx, node, emit, child_done, terminal, env_trunc, real
            )
        if cfg.record_visited:
            self._record_visits(active & ~is_prim & ~child_popped, ctx, node)

        # statistics, then pop
        self.stats.count_ends(self.learner, node, popped, ended_own & popped, self.inv_steps)
        self.stack = torch.where(popped, -1, self.stack)
        self.top = torch.where(real, (active & ~popped).sum(1) - 1, -1)
        self.done = env_term | env_trunc
        return batch

    def _record_visits(
        self, continuing: torch.Tensor, ctx: StepContext, node: torch.Tensor
    ) -> None:
        """Append ``s'`` to the visit buffer of the levels whose child goes on.

        ``s'`` is abstracted for each level's node; visit ``k`` of a child lives in slot
        ``k % L``.
        """
        size = self.config.record_visited
        slot = (self.steps % size).unsqueeze(-1)  # steps already counts this step: visit index
        state = ctx.abstract.gather(1, node)
        for buf, value in (
            (self.vis_state, state),
            (self.vis_steps, self.steps),
            (self.vis_time, self.time),
        ):
            old = buf.gather(2, slot).squeeze(-1)
            buf.scatter_(2, slot, torch.where(continuing, value.to(buf.dtype), old).unsqueeze(-1))

    def _transitions(self, step_td, ctx, node, emit, child_done, terminal, env_trunc, real):
        g = self.graph
        d = self.depth
        stack = self.stack[:, :d]
        node = node[:, :d]
        terminal = terminal[:, :d]
        emit = emit[:, :d]
        child_inst = _shift_left(self.stack, fill=-1)[:, :d]
        parent_inst = _shift_right(self.stack, fill=-1)[:, :d]
        if g.internal_nodes:
            pseudo = g.internal_rewards_at_termination(ctx.obs, self.memory).gather(1, node)
            pseudo = pseudo * terminal
        else:
            pseudo = torch.zeros(node.shape, device=self.device)
        top = self.top
        prim_inst = _at(self.stack, top)
        fields = {
            "valid": emit,
            "learner": self.learner,
            "inst": stack.clone(),
            "node": node,
            "child": self.child[:, :d].clone(),
            "child_inst": child_inst,
            "parent_inst": parent_inst,
            "state": self.start_state[:, :d].clone(),
            "next_state": ctx.abstract.gather(1, node),
            "steps": self.steps[:, :d].clone(),
            "duration": self.time[:, :d].clone(),
            "reward": self.reward[:, :d].clone(),
            "discounted_reward": self.disc_reward[:, :d].clone(),
            "internal_reward": self.internal[:, :d].clone(),
            "pseudo_reward": pseudo,
            "terminal": terminal,
            "child_done": child_done[:, :d] & emit,
            "truncated": env_trunc[:, None] & emit & ~terminal,
            "greedy": self.greedy[:, :d].clone(),
            "own_greedy": self.own_greedy[:, :d].clone(),
            "prim_valid": real & (top >= 0),
            "prim_inst": prim_inst,
            "prim_node": lookup(g.inst_node, prim_inst.clamp_min(0)),
            "prim_state": _at(self.start_state, top),
            "prim_reward": step_td["reward"],
            "prim_duration": step_td["duration"],
            "prim_greedy": _at(self.greedy, top - 1),
            "prim_action": self._action.clone(),
        }
        if ctx.features is not None:
            fields["features"] = self.start_features[:, :d].clone()
            fields["next_features"] = _gather_levels(ctx.features, node)
        if self.config.record_visited:
            fields.update(
                visited_state=self.vis_state[:, :d].clone(),
                visited_steps=self.vis_steps[:, :d].clone(),
                visited_time=self.vis_time[:, :d].clone(),
                visited_valid=self._visit_slots[None, None, :]
                < self.steps[:, :d].clamp_max(self.config.record_visited)[:, :, None],
            )
        return TensorDict(fields, batch_size=[self.batch_size], device=self.device)

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        """Stacks, accumulators and the last action and observation, for exact resume."""
        state = {k: getattr(self, k).clone() for k in self._state_keys}
        state["action"] = self._action.clone()
        state["obs"] = {} if self._obs is None else self._obs.to_dict()
        return state

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore a ``state_dict`` taken from an executor of the same shape."""
        for k in self._state_keys:
            if state[k].shape != getattr(self, k).shape:
                raise ValueError(f"executor state {k!r} has shape {tuple(state[k].shape)}")
        for k in self._state_keys:
            setattr(self, k, state[k].to(self.device).clone())
        self._action = state["action"].to(self.device).clone()
        obs = state["obs"]
        self._obs = TensorDict(obs, batch_size=[self.batch_size]) if obs else None


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
