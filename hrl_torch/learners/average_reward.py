"""Hierarchical average-reward learners of Chapter 4: HAR (Algorithm 1) and RAR (Algorithm 2).

Both measure time as primitive steps ``N`` (discrete time) or durations ``tau`` (continuous
time, ``continuous=True``): one mechanism, the time unit is the only difference. Rewards of a
continuous-time step arrive as the env reports them, ``k(s, a) + r(s, a) tau``.

**Gains** are running sums ``g = R / T`` of reward and time over the segments the gain sees
(``GainEstimate``, float64): HAR's one global gain sees every primitive step whose action and
ancestors were all chosen greedily (Algorithm 1, lines 6-7); RAR's gain of subtask ``i`` sees
every run of a child of ``i`` chosen greedily together with all its ancestors (Algorithm 2,
lines 23-24). A gain with no time yet reads 0. The algorithms leave the initial sums ``r_0``,
``n_0`` open: ``gain_prior=(g_0, t_0)`` starts them as if ``t_0`` time units at gain ``g_0``
had been seen (default ``(0, 0)``: empty sums). An optimistic start (``g_0`` above any
achievable gain) matters in practice: with empty sums the early, poor greedy steps keep the
estimate below the greedy policy's gain for a long time, the undiscounted values of a
continuing root then drift upward, and states refreshed only by exploration look stale and
worse than they are, so exploration stops paying (docs/reproduction.md, Figure 4.3).

**HAR** (hierarchical optimality, tables per instance): the three-part decomposition of
``hrl_torch.learners.three_part`` without discounting, primitives learning average-adjusted
rewards ``H(p, x) <- (1-alpha) H + alpha (r - g t)`` (line 5 and its continuous-time version).

**RAR** (recursive optimality, tables per subtask): ``L^(i, s, a) = H^(a, s) + C(i, s, a)``
with ``H^(i, s) = max_a L^(i, s, a)`` (Eqs. 4.17-4.19; a primitive's ``V^(a, s)`` is its plain
expected reward, line 5), and after child ``a`` ran from ``s`` to ``s'`` in time ``t``::

    C(i, s, a) <- (1-alpha) C + alpha [L^(i, s', a*) - (g_i - g_a) t]      lines 18 / 20

with ``g_a = 0`` for a primitive ``a`` and ``L^(i, s', a*) = 0`` at a terminal ``s'`` (the
dummy state of Figure 4.1). All-states updating uses, for every state visited during the
child, the time left after it (``N`` in line 15 counts from the end of ``ChildSeq``).
"""

from __future__ import annotations

import torch
from torch import nn

from hrl_torch.common.ops import take_flat
from hrl_torch.execution.transitions import LEVEL, PRIMITIVE
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.learners.base import TabularLearner, finished
from hrl_torch.learners.three_part import ThreePartLearner
from hrl_torch.modules.schedules import Schedule


class GainEstimate(nn.Module):
    """Running sums of reward and time per learner and slot; ``gain = reward / time``.

    Args:
        n_learners: population size ``P``.
        n_slots: gains per learner (1 for a global gain, one per table for RAR).
        prior: ``(g_0, t_0)``: initial sums ``(g_0 t_0, t_0)``.
    """

    def __init__(
        self, n_learners: int, n_slots: int = 1, prior: tuple[float, float] = (0.0, 0.0)
    ) -> None:
        super().__init__()
        self.n_slots = n_slots
        g0, t0 = (float(x) for x in prior)
        shape = (n_learners, n_slots)
        self.register_buffer("reward", torch.full(shape, g0 * t0, dtype=torch.float64))
        self.register_buffer("time", torch.full(shape, t0, dtype=torch.float64))

    @property
    def gain(self) -> torch.Tensor:
        """``[P, n_slots]`` float32: total reward over total time (0 before any time)."""
        g = self.reward / self.time.clamp_min(1e-300)
        return torch.where(self.time > 0, g, 0.0).float()

    def add(
        self,
        learner: torch.Tensor,
        slot: torch.Tensor | int,
        reward: torch.Tensor,
        time: torch.Tensor,
        mask: torch.Tensor,
    ) -> None:
        """Add the segments where ``mask`` (all arguments broadcast together)."""
        if isinstance(slot, torch.Tensor):
            learner, slot, reward, time, mask = torch.broadcast_tensors(
                learner, slot, reward, time, mask
            )
        else:  # (a fixed slot: no tensor made from host data each step)
            learner, reward, time, mask = torch.broadcast_tensors(learner, reward, time, mask)
        idx = (learner * self.n_slots + slot).reshape(-1)
        m = mask.reshape(-1).double()
        self.reward.view(-1).index_add_(0, idx, reward.reshape(-1).double() * m)
        self.time.view(-1).index_add_(0, idx, time.reshape(-1).double() * m)


class HARLearner(ThreePartLearner):
    """Hierarchically optimal average reward RL (Algorithm 1) for ``P`` learners.

    Args:
        graph: the task graph (its root is continuing).
        n_learners: population size ``P``.
        alpha: step size (number or schedule).
        all_states: all-states updating (Algorithm 1, line 16; needs ``record_visited``).
        continuous: continuous-time HAR (durations ``tau`` instead of steps).
        init: initial completion values ``C``.
        ce_init: initial external completions ``CE`` (default: ``init``).
        gain_prior: ``(g_0, t_0)``, initial sums of the gain (see the module docstring).
    """

    uses = frozenset({"parent_inst", "primitive", "greedy"})

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        alpha: float | Schedule = 0.5,
        all_states: bool = False,
        continuous: bool = False,
        init: float = 0.0,
        ce_init: float | None = None,
        gain_prior: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        super().__init__(graph, n_learners, alpha, 1.0, all_states, continuous, init, ce_init)
        self.gains = GainEstimate(n_learners, 1, gain_prior)

    @property
    def gain(self) -> torch.Tensor:
        """The global gain of every learner ``[P]``."""
        return self.gains.gain[:, 0]

    def discount(self, t: torch.Tensor) -> torch.Tensor:
        """No discounting: average-adjusted values."""
        return torch.ones_like(t)

    def primitive_target(self, batch) -> torch.Tensor:
        """``r - g t`` (line 5; continuous time: ``k + r tau - g tau``)."""
        prim = batch[PRIMITIVE]
        return prim["reward"] - self.gain[batch["learner"]] * self.primitive_time(batch)

    def update(self, batch, step: int) -> None:
        """Lines 5, 17-21 (all with the gain ``g_t``), then the gain (lines 6-7)."""
        prim = batch[PRIMITIVE]
        super().update(batch, step)
        seen = prim["valid"] & prim["greedy"]  # M_i and its ancestors non-random
        self.gains.add(batch["learner"], 0, prim["reward"], self.primitive_time(batch), seen)


class RARLearner(TabularLearner):
    """Recursively optimal average reward RL (Algorithm 2) for ``P`` learners.

    Args:
        graph: the task graph (its root is continuing).
        n_learners: population size ``P``.
        alpha: step size (number or schedule).
        all_states: all-states updating (Algorithm 2, line 15; needs ``record_visited``).
        continuous: continuous-time RAR (durations ``tau`` instead of steps).
        init: initial completion values ``C``.
        gain_prior: ``(g_0, t_0)``, initial sums of every subtask's gain.
    """

    uses = frozenset({"greedy", "primitive"})
    value_keys = ("H", "Q")

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        alpha: float | Schedule = 0.5,
        all_states: bool = False,
        continuous: bool = False,
        init: float = 0.0,
        gain_prior: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        super().__init__(graph, n_learners, alpha, 1.0, per_instance=False)
        self.all_states = all_states
        self.continuous = continuous
        self.C = self.completion_bank(init)
        self.V = self.primitive_bank()
        self.share_store(C=self.C, V=self.V)
        self.attach_heads(C=self.C, V=self.V)
        self.gains = GainEstimate(n_learners, self.layout.n_tables, gain_prior)

    @property
    def gain(self) -> torch.Tensor:
        """Gain of every subtask ``[P, n_tables]`` (0 for primitives)."""
        return self.gains.gain

    def evaluate(self, ctx: StepContext) -> None:
        """Bottom-up ``H^(i, s) = max_a L^(i, s, a)`` (Eqs. 4.17-4.19) and the rows ``L^``."""
        blocked, dead, (c,) = self.composite_rows(ctx, self.C)
        value = self.primitive_values(ctx, self.V)
        q_rows = []
        for ids, kids, unavailable, gone, c_part in self.groups(blocked, dead, c):
            q = take_flat(value, kids) + c_part
            best = q.masked_fill(unavailable, -torch.inf).amax(-1)
            value.index_copy_(1, ids, best.masked_fill(gone, 0.0))
            q_rows.append(q)
        ctx.values["H"] = value
        ctx.values["Q"] = torch.cat(q_rows, 1)

    def update(self, batch, step: int) -> None:
        """Lines 5, 18/20 (with the gains ``g_t``), then the gains (lines 23-24)."""
        level, prim = batch[LEVEL], batch[PRIMITIVE]
        alpha = self.alpha(step)
        lay = self.layout
        inst = level["inst"]
        learner = batch["learner"][:, None].expand_as(inst)
        table = lay.inst_table[inst.clamp_min(0)]
        child_table = lay.table_children[table, level["child"]].clamp_min(0)
        terminal = level["terminal"]
        valid = finished(level)
        t = self.time_of(batch)
        gains = self.gain
        g_i = gains[learner, table]
        g_a = torch.where(lay.table_is_primitive[child_table], 0.0, gains[learner, child_table])
        h_next = batch["values", "H"].gather(1, table)
        h_next = torch.where(terminal, torch.zeros_like(h_next), h_next)  # dummy state: 0
        target = h_next - (g_i - g_a) * t
        idx = self.C.index(learner, table, level["state"], level["child"])
        self.record_td(learner, level["node"], target - self.C.read(idx, valid), valid)
        self.C.update(idx.reshape(-1), target.reshape(-1), alpha, valid.reshape(-1))
        if self.all_states and "visited_state" in level.keys():
            left = t[..., None] - self.time_of(batch, "visited_steps", "visited_time")
            target_k = h_next[..., None] - (g_i - g_a)[..., None] * left
            self.update_visited(batch, table, valid, alpha, [(self.C, target_k)])
        prim_table = lay.inst_table[prim["inst"].clamp_min(0)]
        pidx = self.V.index(batch["learner"], prim_table, prim["state"], 0)
        self.V.update(pidx, prim["reward"], alpha, prim["valid"])  # line 5
        # lines 23-24: the child's run counts for g_i when it and its ancestors were greedy
        seen = level["valid"] & level["greedy"]
        self.gains.add(learner, table, level["reward"], t, seen)
