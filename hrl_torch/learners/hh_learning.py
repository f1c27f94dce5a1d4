"""HH-learning (Seri and Tadepalli 2002): model-based, average-adjusted w.r.t. the global gain.

Every subtask ``i`` (tables per subtask) learns the model of its children, the distribution of
the state ``s'`` where child ``a`` ends when started in ``s`` (``P_i(s' | s, a)``, from counts;
``s'`` terminal for ``i`` is one extra outcome), and every primitive its mean reward ``r(s, p)``
and duration ``tau(s, p)``. The values solve Eq. 4.12 with the global gain ``g``::

    H(p, s) = r(s, p) - g tau(s, p)                                  primitive p
    H(i, s) = 0                                                      s terminal for i
    H(i, s) = max_a [H(a, s) + sum_s' P_i(s' | s, a) H(i, s')]      otherwise

by asynchronous value iteration: every step, every subtask backs up the state it is in (its
abstract state at the current observation) with the current model, ``H(i, s) <- max_a [...]``.
A child with no model data yet continues with 0 (the value of terminating), and a primitive
never tried is worth 0. The gain is a
running sum over greedy primitive steps, as HAR's (``GainEstimate``); H-learning's original
gain update (Tadepalli and Ok 1998) is a step-size recursion on ``r - g + h(s') - h(s)``.

The model is dense (``[S_i, A_i, S_i + 1]`` counts per subtask), for small domains only.
"""

from __future__ import annotations

import torch

from hrl_torch.common.ops import columns
from hrl_torch.execution.transitions import LEVEL, PRIMITIVE
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners.average_reward import GainEstimate
from hrl_torch.learners.base import TabularLearner, finished
from hrl_torch.modules.tables import TableBank


class HHLearner(TabularLearner):
    """HH-learning for a population of ``P`` learners.

    Args:
        graph: the task graph (its root is continuing).
        n_learners: population size ``P``.
        continuous: primitives cost ``g tau`` (continuous time) instead of ``g`` per step.
        gain_prior: ``(g_0, t_0)``, initial sums of the gain (``GainEstimate``).
        max_model_entries: refuse graphs whose dense model would exceed this many counts per
            learner.
    """

    value_keys = ("H", "Q", "H_index")

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        continuous: bool = False,
        gain_prior: tuple[float, float] = (0.0, 0.0),
        max_model_entries: int = 20_000_000,
    ) -> None:
        super().__init__(graph, n_learners, alpha=1.0, gamma=1.0, per_instance=False)
        self.continuous = continuous
        lay = self.layout
        composite = ~lay.table_is_primitive
        n_states = torch.where(composite, lay.table_n_states, 0)
        outcomes = n_states + 1  # every abstract state, and "terminated"
        n_cols = lay.table_n_children * outcomes
        entries = int((n_states * n_cols).sum())
        if entries > max_model_entries:
            raise GraphError(
                f"HH-learning's dense model needs {entries:,} counts per learner "
                f"(> {max_model_entries:,}); it is meant for small domains"
            )
        self.register_buffer("outcomes", outcomes, persistent=False)
        self.width = int(outcomes.max())
        self.model = TableBank(n_learners, n_states, n_cols.clamp_min(1))
        self.H = TableBank(n_learners, n_states, torch.ones_like(n_states))
        prim_states = torch.where(composite, 0, lay.table_n_states)
        ones = torch.ones_like(prim_states)
        self.prim_count = TableBank(n_learners, prim_states, ones)
        self.prim_reward = TableBank(n_learners, prim_states, ones)
        self.prim_time = TableBank(n_learners, prim_states, ones)
        self.attach_heads(
            model=self.model,
            H=self.H,
            count=self.prim_count,
            reward=self.prim_reward,
            time=self.prim_time,
        )
        self.gains = GainEstimate(n_learners, 1, gain_prior)

    @property
    def gain(self) -> torch.Tensor:
        """The global gain of every learner ``[P]``."""
        return self.gains.gain[:, 0]

    def evaluate(self, ctx: StepContext) -> None:
        """Bottom-up backups ``max_a [H(a, s) + E H(i, s')]`` (Eq. 4.12) at ``ctx``.

        ``ctx.values``: ``H`` ``[B, T]``, the rows ``Q`` ``[B, Tc, A]`` (plan order) and
        ``H_index`` ``[B, Tc]``, where each subtask's backup goes (``update``).
        """
        lay, plan = self.layout, self.plan
        b, dev = ctx.abstract.shape[0], ctx.abstract.device
        learner = ctx.learner[:, None]
        value = torch.zeros(b, lay.n_tables, device=dev)
        prims = plan.prims
        idx = self.prim_count.index(learner, prims, columns(ctx.abstract, plan.prim_node), 0)
        count = self.prim_count.read(idx)
        r = self.prim_reward.read(idx) / count.clamp_min(1.0)
        tau = self.prim_time.read(idx) / count.clamp_min(1.0)
        if not self.continuous:
            tau = torch.ones_like(tau)  # every primitive step costs g
        h = r - self.gain[ctx.learner][:, None] * tau
        value[:, prims] = torch.where(count > 0, h, 0.0)  # no data yet: 0
        outcome = torch.arange(self.width, device=dev)
        child = torch.arange(lay.max_children, device=dev)
        q_rows = []
        for (start, end), ids in zip(plan.bounds, plan.group_ids, strict=True):
            part = slice(start, end)
            nodes = plan.node[part]
            available = columns(ctx.available, nodes)
            n_out = self.outcomes[ids][None, :, None]
            # H(i, s') for every outcome s' (the last one, "terminated", is worth 0)
            h_ok = outcome[None, None, :] < n_out - 1
            h_idx = self.H.index(learner[..., None], ids[None, :, None], outcome, 0)
            h_next = self.H.read(h_idx.expand(b, -1, -1), h_ok.expand(b, -1, -1))
            state = columns(ctx.abstract, nodes)
            m_ok = (outcome < n_out[..., None]) & available[..., None]
            col = child[None, None, :, None] * n_out[..., None] + outcome
            m_idx = self.model.index(
                learner[..., None, None], ids[None, :, None, None], state[..., None, None], col
            )
            counts = self.model.read(m_idx, m_ok.expand(b, -1, -1, -1))  # [B, n, A, W]
            total = counts.sum(-1)
            cont = (counts * h_next[:, :, None, :]).sum(-1) / total.clamp_min(1.0)
            q = value[:, plan.child_table[part]] + cont
            best = torch.where(available, q, -torch.inf).amax(-1)
            dead = columns(ctx.blocked, nodes) | ~available.any(-1)
            value[:, ids] = best.masked_fill(dead, 0.0)
            q_rows.append(q)
        ctx.values["H"] = value
        ctx.values["Q"] = torch.cat(q_rows, 1)
        state = columns(ctx.abstract, plan.node)
        ctx.values["H_index"] = self.H.index(learner, plan.order, state, 0)

    def update(self, batch, step: int) -> None:
        """Back up the states every subtask is in, then add the batch to the models and gain."""
        level, prim = batch[LEVEL], batch[PRIMITIVE]
        lay = self.layout
        self._backup(batch["values"])
        # the model of every finished child: counts of (s, a) -> s' (or "terminated")
        inst = level["inst"]
        table = lay.inst_table[inst.clamp_min(0)]
        terminal = level["terminal"]
        valid = finished(level)
        n_out = self.outcomes[table]
        outcome = torch.where(terminal, n_out - 1, level["next_state"])
        col = level["child"] * n_out + outcome
        m_idx = self.model.index(batch["learner"][:, None], table, level["state"], col)
        m_idx = torch.where(valid, m_idx, torch.zeros_like(m_idx)).reshape(-1)
        self.model.data.view(-1).index_add_(0, m_idx, valid.reshape(-1).float())
        # primitive rewards and durations
        prim_table = lay.inst_table[prim["inst"].clamp_min(0)]
        p_idx = self.prim_count.index(batch["learner"], prim_table, prim["state"], 0)
        seen = prim["valid"]
        p_idx = torch.where(seen, p_idx, torch.zeros_like(p_idx))
        m = seen.float()
        self.prim_count.data.view(-1).index_add_(0, p_idx, m)
        self.prim_reward.data.view(-1).index_add_(0, p_idx, prim["reward"] * m)
        self.prim_time.data.view(-1).index_add_(0, p_idx, prim["duration"] * m)
        greedy = seen & prim["greedy"]
        self.gains.add(batch["learner"], 0, prim["reward"], self.primitive_time(batch), greedy)

    def _backup(self, values) -> None:
        """``H(i, s) <- max_a [...]`` for every subtask at the states it was evaluated at."""
        index = values["H_index"]
        backup = values["H"][:, self.plan.order]
        ok = torch.ones_like(backup, dtype=torch.bool)
        self.H.update(index.reshape(-1), backup.reshape(-1), 1.0, ok.reshape(-1))
