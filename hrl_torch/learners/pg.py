"""Policy-gradient learners (Chapter 5): HPGRL (Algorithm 3), flat PGRL and actor-critic.

Every policy-gradient (PG) node ``i`` has a parameterised policy ``mu_i(a|s; theta_i)``, its
*policy head* (``hrl_torch.modules.heads.PolicyHead``): by default a softmax with one parameter per
(abstract state, child) when its children are discrete, or a Gaussian over CMAC tiles of its
continuous features when its only child is a continuous primitive (``hrl_torch.modules.policies``);
any ``PolicyHead`` subclass can be given instead. Nodes may share parameters by naming the same
*group* (the ship's four diagonal directions share one low-level policy). Updates (Algorithm 3,
lines 11-16, with Equation 5.3), after child ``a`` of ``i`` ran from ``s`` to ``s'`` with
external reward ``R`` (summed over the child) and internal reward ``r~_i`` of ``i``::

    z_{k+1} = z_k + grad mu_i(a|s) / mu_i(a|s)          z = 0 at the renewal state s_i^*
    theta_{k+1} = theta_k + alpha_k (R + r~_i) z_{k+1}

so each invocation of ``i`` is one renewal cycle: ``z`` restarts at 0 when ``i`` is invoked, and
``r~_i`` (pseudo rewards, shaping, or a reward computed from the node's own features at ``s'``)
is used by ``i`` only: its parent sees ``R`` alone (the executor never adds internal rewards to
the external accumulators). Over one cycle the updates sum to ``alpha F_m`` of Equation 5.2,
``F_m = sum_n R_n grad mu / mu`` with ``R_n`` the reward-to-go, an unbiased estimate of the
gradient of the weighted reward-to-go ``chi_i`` (Proposition 5.1).

Eligibilities are sparse: per env row and stack depth holding a PG node, the likelihood-ratio
terms of the current invocation as ``(flat parameter index, value)`` pairs in a ring of
``trace_len`` entries, with the cycle's reward so far when each was added. ``online=True``
applies line 16 at every step (cost: the invocation's length per row and step);
``online=False`` applies the same sum once at the renewal, ``sum_n g_n (C_end - C_{n-1})``
(Equation 5.2; cost per row and step independent of the cycle's length). ``beta < 1``
discounts the eligibility, ``z_{k+1} = beta z_k + grad mu / mu`` (Baxter & Bartlett 2001; a
biased, lower-variance member of the family Section 5.2 allows for lines 11-16); ``beta = 1`` is
Equation 5.3. With ``E`` envs per learner the rows' updates are summed into the learner's shared
parameters.

``ActorCriticLearner`` is the flat actor-critic baseline of Section 5.3 (Konda 2002): the actor
is a tile-coded Gaussian as in flat PGRL, the critic a tile-coded ``Q(s, a)`` learned by
SARSA(0); the actor steps ``beta (Q(s, a) - Q(s, a_mean)) grad log mu(a|s)`` every step.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence

import torch
from torch import nn

from hrl_torch.common.devices import DeferredCheck
from hrl_torch.common.ops import lookup
from hrl_torch.common.rng import LevelDraws
from hrl_torch.execution.transitions import LEVEL, PRIMITIVE, Choice
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners import pg_traces
from hrl_torch.learners.base import Learner
from hrl_torch.learners.pg_config import PGConfig
from hrl_torch.learners.pg_stats import PGStats
from hrl_torch.learners.pg_traces import (
    apply_traces,
    check_overflow,
    overflow_error,
    ring_entries,
    value_baseline_traces,
)
from hrl_torch.learners.validate import check_fraction, check_positive, check_step_size
from hrl_torch.modules.heads import PolicyChoice, PolicyHead, PolicyInput, TileValueHead
from hrl_torch.modules.policies import SoftmaxPolicyHead, TileGaussianPolicyHead, squash
from hrl_torch.modules.schedules import Schedule, as_schedule
from hrl_torch.modules.tables import TableBank
from hrl_torch.modules.tiles import TileCoder

FeatureReward = Callable[[torch.Tensor], torch.Tensor]


def invocation_ended(batch, depths: torch.Tensor) -> torch.Tensor:
    """``[B, S]``: the invocation at each stack depth in ``depths [S]`` ended in this batch.

    A level ``d >= 1`` is popped exactly when its parent (level ``d - 1``) emits a transition;
    the root ends with the episode (or by its own termination).
    """
    level = batch[LEVEL]
    root_end = level["terminal"][:, 0] | level["truncated"][:, 0]
    parent = (depths - 1).clamp_min(0)
    return torch.where(
        depths[None, :] == 0, root_end[:, None], level["valid"].index_select(1, parent)
    )


class HPGRLLearner(Learner):
    """HPGRL (Algorithm 3) over the PG nodes of a graph; flat PGRL on a one-level graph.

    Args:
        graph: the task graph.
        n_learners: population size ``P``.
        config: step size, Gaussian width, update mode, trace length.
        nodes: the PG nodes: names (each its own parameter group) or ``{name: group}``
            (nodes of one group share parameters). Default: every subtask.
        coder: tile coder of the Gaussian nodes' features (required when there are any).
        feature_reward: ``{node name: fn}``, an internal reward ``fn(next_features [R, F]) ->
            [R]`` of the node computed from its own features at ``s'`` (for nodes whose
            internal reward depends on invocation memory, e.g. a local frame).
    """

    deferred_overflow: DeferredCheck | None = None  #: set by ``deferred_checks``
    ring_entries = ring_entries  #: ``Learner.ring_entries`` (``pg_traces``)
    overflow_error = overflow_error  #: (``pg_traces``)

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        config: PGConfig | None = None,
        nodes: Sequence[str] | Mapping[str, str] | None = None,
        coder: TileCoder | None = None,
        feature_reward: Mapping[str, FeatureReward] | None = None,
        heads: Mapping[str, PolicyHead] | None = None,
    ) -> None:
        super().__init__(graph, n_learners)
        self.config = cfg = config or PGConfig()
        check_positive(self, "alpha", cfg.alpha, one_for_all=True)
        check_fraction(self, "beta", cfg.beta)
        self.alpha = as_schedule(cfg.alpha)
        if nodes is None:
            nodes = [graph.names[k] for k in graph.subtasks()]
        groups = dict(nodes) if isinstance(nodes, Mapping) else {n: n for n in nodes}
        self.coder = coder
        self._build_heads(groups, dict(heads or {}))
        by_fn: dict[int, tuple[FeatureReward, list[int]]] = {}
        for name, fn in (feature_reward or {}).items():
            by_fn.setdefault(id(fn), (fn, []))[1].append(graph.index[name])
        # one call per distinct function: [(fn, node indices using it)]
        self.feature_reward = [(fn, torch.tensor(ks)) for fn, ks in by_fn.values()]
        self.register_buffer("grad_sum", torch.zeros_like(self.theta), persistent=False)
        self.register_buffer(
            "cycles", torch.zeros(n_learners, len(self.group_names)), persistent=False
        )
        self.register_buffer("reward_to_go_mean", torch.zeros(n_learners, len(self.group_names)))
        self._rows: dict[str, torch.Tensor] = {}
        self.pg_stats = PGStats(n_learners, self.theta, len(self.group_names))
        self.value_rate = cfg.value_rate
        if self.value_rate:  # the state baseline's table (``value_baseline_traces``)
            self.register_buffer("value_table", torch.zeros_like(self.theta))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        if self.value_rate:  # (a checkpoint of a rule without the state baseline: V from 0)
            state_dict.setdefault(prefix + "value_table", torch.zeros_like(self.value_table))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def log_scalars(self, step: int) -> dict[str, list[float]]:
        """Per PG group and learner: returns, policy, update norms (``pg_stats``), at a log."""
        return self.pg_stats.scalars(self, step)

    # ------------------------------------------------------------------ heads
    def default_head(self, group: str, node: int) -> PolicyHead:
        """Softmax over discrete children; a tile-coded Gaussian for a continuous child."""
        g, cfg = self.graph, self.config
        x = g.nodes[node]
        children = [g.node(c) for c in x.children_names]
        if len(children) == 1 and children[0].is_primitive and children[0].action_dim > 0:
            if self.coder is None:
                raise GraphError(f"PG node {x.name!r} has a continuous child but no coder")
            return TileGaussianPolicyHead(
                group, self.coder, cfg.sigma, cfg.action_low, cfg.action_high
            )
        return SoftmaxPolicyHead(group, x.n_states, len(children), g.max_children)

    def _build_heads(self, groups: dict[str, str], heads: dict[str, PolicyHead]) -> None:
        """One head per group (given or default), its block of the flat ``theta``, batches."""
        g = self.graph
        names: list[str] = []
        node_group = torch.full((g.n_nodes,), -1, dtype=torch.long)
        for name, group in groups.items():
            k = g.index[name]
            if g.nodes[k].is_primitive:
                raise GraphError(f"PG node {name!r} is a primitive")
            if group not in heads:
                heads[group] = self.default_head(group, k)
            heads[group].check(g, k)
            if group not in names:
                names.append(group)
            node_group[k] = names.index(group)
        self.group_names, self._pg_nodes = names, {g.index[n] for n in groups}  # (host copy)
        self.heads = nn.ModuleDict({n: heads[n] for n in names})
        shape = torch.tensor([[heads[n].n_states, heads[n].n_cols] for n in names]).view(-1, 2)
        self.params = TableBank(self.n_learners, shape[:, 0], shape[:, 1], self.config.init)
        self.params.save_store = False
        for t, name in enumerate(names):
            self.heads[name].bind(self.params, t)
        self.total, self.sentinel = self.params.total, self.params.sentinel
        self.width = max([self.heads[n].width for n in names] + [1])
        self.has_gauss = any(self.heads[n].continuous for n in names)
        self.n_uniforms = max([self.heads[n].n_uniforms for n in names] + [3])  # (per choice)
        self.action_width = max(g.action_dim, 1)  # (of a continuous choice)
        # heads stepping themselves (their optimizer over line 16's estimate)
        self._stepped = [(t, h) for t, h in enumerate(self.heads.values()) if h.steps_itself]
        # heads that share an ``act`` call, and the groups each call serves
        batches: dict[object, list[int]] = {}
        for t, name in enumerate(names):
            batches.setdefault(self.heads[name].batch_key(), []).append(t)
        self._batches = [(self.heads[names[ts[0]]], ts[0]) for ts in batches.values()]
        group_batch = torch.zeros(len(names), dtype=torch.long)  # each group's batch
        for i, ts in enumerate(batches.values()):
            group_batch[ts] = i
        self.register_buffer("group_batch", group_batch, persistent=False)
        self.register_buffer("node_group", node_group, persistent=False)
        pg_inst = node_group[g.inst_node] >= 0
        depths = sorted({int(d) for d in g.inst_depth[pg_inst]})
        depth_slot = torch.full((g.max_levels,), len(depths), dtype=torch.long)
        depth_slot[depths] = torch.arange(len(depths))
        self.register_buffer("depths", torch.tensor(depths, dtype=torch.long), persistent=False)
        self.register_buffer("depth_slot", depth_slot, persistent=False)

    @property
    def theta(self) -> torch.Tensor:
        """Every learner's parameters, flat ``[P * total + 1]`` (last: a sentinel, always 0)."""
        return self.params.store

    def group_view(self, group: str, learner: int = 0, buffer: str = "theta") -> torch.Tensor:
        """One group's block of ``theta`` (or ``grad_sum``) for one learner, as a view.

        Softmax groups are ``[n_states, n_children]``, Gaussian groups ``[n_tiles]``.
        """
        k = self.group_names.index(group)
        head = self.heads[group]
        whole = {"theta": self.theta, "grad_sum": self.grad_sum}[buffer]
        flat = whole[: self.sentinel].view(self.n_learners, self.total)
        start, size = int(self.params.offset[k]), head.n_states * head.n_cols
        block = flat[learner, start : start + size].view(head.n_states, head.n_cols)
        if head.continuous:
            return block[0]
        return block[:, : head.n_children]

    # ------------------------------------------------------------------ per-row state
    def _pair_base(self, b: int, device: torch.device) -> torch.Tensor:
        """``[B, S]``: the first ring slot of every (row, depth) pair in the flat rings."""
        cached = self.__dict__.get("_pair_base_cache")
        if cached is None or cached.shape[0] != b or cached.device != device:
            s, k1 = len(self.depths), self.config.trace_len + 1
            cached = torch.arange(b * s, device=device).view(b, s) * k1
            self.__dict__["_pair_base_cache"] = cached
        return cached

    def _row_state(self, b: int, device: torch.device) -> dict[str, torch.Tensor]:
        rows = self._rows
        if not rows or rows["count"].shape[0] != b:
            s, k, w = len(self.depths), self.config.trace_len, self.width
            long = dict(dtype=torch.long, device=device)
            rows.clear()
            rows.update(
                index=torch.full((b, s, k + 1, w), self.sentinel, **long),
                value=torch.zeros(b, s, k + 1, w, device=device),
                reward=torch.zeros(b, s, k + 1, device=device),
                count=torch.zeros(b, s, **long),
            )
        return rows

    @property
    def score_width(self) -> int:
        """Nonzeros of one choice's likelihood-ratio term (the executor keeps them per level)."""
        return self.width

    def get_extra_state(self) -> dict:
        """Eligibility traces of the training rows (checkpoints)."""
        return {k: v.clone() for k, v in self._rows.items()}

    def set_extra_state(self, state: dict) -> None:
        """Restore ``get_extra_state``.

        Ring indices are clamped into ``theta`` as ``update`` keeps them (an older checkpoint
        may hold others in unused entries).
        """
        self._rows = {k: v.clone() for k, v in state.items()}
        if "index" in self._rows:
            self._rows["index"].clamp_(0, self.sentinel)

    # ------------------------------------------------------------------ acting
    def select(
        self,
        inst: torch.Tensor,
        ctx: StepContext,
        available: torch.Tensor,
        u: torch.Tensor,
        greedy: bool = False,
        step: int = 0,
        rows: torch.Tensor | None = None,
    ) -> Choice:
        """Choose children of PG instances ``inst [B]`` (other rows: ignored values).

        ``rows [R]``: ``inst``, ``available`` and ``u`` are those batch rows' (``ctx`` is the
        whole batch's); ``None``: every row.

        ``u [B, n_uniforms]`` uniforms (a softmax sample, two per pair of normals). Each node's
        head chooses for its rows; with ``greedy`` it takes the mode, otherwise it samples and
        the choice carries its likelihood-ratio term (``score_index``/``score_value``), which
        the executor keeps on the stack until the child ends and hands to ``update``.
        Every row is computed (static shapes, no host read); the rows off PG nodes keep the
        defaults.
        """
        g, b, dev = self.graph, inst.shape[0], inst.device
        choice = torch.zeros(b, dtype=torch.long, device=dev)
        flag = torch.full((b,), greedy, dtype=torch.bool, device=dev)
        action = torch.zeros(b, self.action_width, device=dev) if self.has_gauss else None
        index = torch.full((b, self.width), self.sentinel, dtype=torch.long, device=dev)
        score = torch.zeros(b, self.width, device=dev)
        out = Choice(choice, flag, action, None if greedy else index, None if greedy else score)
        node = lookup(g.inst_node, inst)
        gid = lookup(self.node_group, node)
        on_pg = gid >= 0
        ctx_rows = torch.arange(b, device=dev) if rows is None else rows
        at = ctx_rows * g.n_nodes + node  # (row, node) in the context's flat [B * N, ...] fields
        features = None
        if ctx.features is not None:
            features = ctx.features.view(-1, ctx.features.shape[2]).index_select(0, at)
            features = torch.where(on_pg[:, None], features, 0.0)
        gid = gid.clamp_min(0)
        inp = PolicyInput(
            base=lookup(self.params.offset, gid),  # (+ the learner's block: ``_act_heads``)
            state=torch.where(on_pg, torch.take(ctx.abstract, at), 0),
            features=features,
            available=available,
            u=u,
            step=step,
        )
        part = self._act_heads(inp, gid, greedy, ctx.learner[ctx_rows] * self.total)
        out.child = torch.where(on_pg, part.child, choice)
        out.greedy = torch.where(on_pg, part.greedy, flag)
        if action is not None and part.action is not None:
            out.action = torch.where(on_pg[:, None], part.action, action)
        if not greedy:
            out.score_index = torch.where(on_pg[:, None], part.index, index)
            out.score_value = torch.where(on_pg[:, None], part.score, score)
        return out

    def _act_heads(self, inp: PolicyInput, gid, greedy: bool, block) -> PolicyChoice:
        """Every batch of heads acts on every row, each row keeping its own batch's choice.

        ``inp.base`` is the offset of each row's group, ``block [n]`` that of its learner; a
        row of another batch is shown the batch's first group at state 0 (static shapes).
        """
        n, dev = gid.shape[0], gid.device
        index = torch.full((n, self.width), self.sentinel, dtype=torch.long, device=dev)
        score = torch.zeros(n, self.width, device=dev)
        child = torch.zeros(n, dtype=torch.long, device=dev)
        flag = torch.full((n,), greedy, dtype=torch.bool, device=dev)
        action = torch.zeros(n, self.action_width, device=dev) if self.has_gauss else None
        for i, (head, first) in enumerate(self._batches):
            mine, part = None, inp
            if len(self._batches) > 1:
                mine = lookup(self.group_batch, gid) == i
                first = self.params.offset[first]
                part = dataclasses.replace(
                    inp,
                    base=torch.where(mine, inp.base, first),
                    state=torch.where(mine, inp.state, 0),
                )
            out = head.act(self.theta, dataclasses.replace(part, base=part.base + block), greedy)
            pad = (0, self.width - out.index.shape[1])
            if pad[1]:
                out.index = torch.nn.functional.pad(out.index, pad, value=self.sentinel)
                out.score = torch.nn.functional.pad(out.score, pad)
            part = (out.child, out.greedy, out.index, out.score)
            if mine is None:
                child, flag, index, score = part
            else:
                child, flag = torch.where(mine, part[0], child), torch.where(mine, part[1], flag)
                index = torch.where(mine[:, None], part[2], index)
                score = torch.where(mine[:, None], part[3], score)
            if out.action is not None:  # ([n] or [n, D]: as [n, D])
                act = out.action if out.action.dim() == 2 else out.action[:, None]
                act = act.expand(n, self.action_width)
                action = act if mine is None else torch.where(mine[:, None], act, action)
        return PolicyChoice(child, flag, action, index, score)

    def make_policy(self, exploration, rng, evaluate: bool = False) -> PGPolicy:
        """The policy of a graph whose nodes are all PG.

        Training samples from the policies whatever ``exploration`` is (PG nodes explore by
        their own randomness); ``evaluate=True`` acts on their modes and records nothing.
        """
        if set(self.graph.subtasks()) - self._pg_nodes:
            raise GraphError(
                "not every subtask is a PG node: use hrl_torch.learners.hybrid.HybridLearner"
            )
        return PGPolicy(self, rng, greedy=evaluate)

    # ------------------------------------------------------------------ learning
    def rewards(self, batch, node: torch.Tensor, depths: torch.Tensor) -> torch.Tensor:
        """``R + r~_i`` ``[B, S]`` of the transitions at ``depths``.

        External reward of the child plus the node's shaping, pseudo and feature-based
        internal rewards.
        """
        level = batch[LEVEL]
        r = (level["reward"] + level["internal_reward"] + level["pseudo_reward"]).index_select(
            1, depths
        )
        if self.feature_reward:
            feats = level["next_features"].index_select(1, depths)
            for fn, fn_nodes in self.feature_reward:
                uses = (node[..., None] == fn_nodes.to(node.device)).any(-1)
                r = r + torch.where(uses, fn(feats.reshape(-1, feats.shape[-1])).view_as(r), 0.0)
        return r

    def update(self, batch, step: int) -> None:
        """Lines 11-16 of Algorithm 3 for every PG transition in ``batch``."""
        level = batch[LEVEL]
        cfg, depths = self.config, self.depths
        b = batch.batch_size[0]
        rows = self._row_state(b, self.theta.device)
        node = level["node"].index_select(1, depths)
        valid = level["valid"].index_select(1, depths) & (torch.take(self.node_group, node) >= 0)
        r = self.rewards(batch, node, depths)
        count, k = rows["count"], cfg.trace_len
        check_overflow(self, valid & (count >= k), node)
        # line 14: z_{k+1} = z_k + grad mu / mu (the ended child's choice joins the ring):
        # one slot per (row, depth), the last (k) for the pairs with nothing to add
        slot = self._pair_base(b, valid.device) + torch.where(valid, count, k).clamp_max(k)
        slot = slot.view(-1)
        for key, src in (("index", "score_index"), ("value", "score_value")):
            ring, new = rows[key], level[src].index_select(1, depths).flatten(0, 1)
            if key == "index":  # (every ring entry stays an index into theta)
                new = new.clamp(0, self.sentinel)
            ring.view(-1, ring.shape[-1]).index_copy_(0, slot, new)
        rows["reward"].view(-1).index_copy_(0, slot, r.reshape(-1))
        rows["count"] = count = (count + valid).clamp_max(k)  # (past k: an overflow, raised)
        ended = invocation_ended(batch, depths) & (count > 0)
        # line 16: every entry of z weighted by this step's R + r~ now (online), or by its
        # reward-to-go once the cycle ends (Equation 5.2)
        cell = batch["learner"][:, None] * len(self.group_names) + torch.take(
            self.node_group, node
        ).clamp(0)
        alpha, before = self.alpha(step), pg_traces.head_blocks(self) if not cfg.frozen else []
        self.apply_traces(rows, valid if cfg.online else ended, alpha, cell)
        pg_traces.step_heads(self, before, alpha)  # (a head's own optimizer over the same estimate)
        if cfg.frozen:  # (cycles ended per learner and group)
            self.cycles.view(-1).index_add_(0, cell.view(-1), ended.view(-1).float())
        self.pg_stats.record(rows["reward"], count, ended, cell)  # (returns per invocation)
        rows["count"] = count.masked_fill(ended, 0)

    def apply_traces(self, rows, pairs: torch.Tensor, alpha, cell: torch.Tensor) -> None:
        """Line 16 over the rings of the pairs ``pairs [B, S]`` (``pg_traces``).

        With a ``value_rate``: less the state baseline ``V(s_n)`` (``value_baseline_traces``).
        """
        (value_baseline_traces if self.config.value_rate else apply_traces)(
            self, rows, pairs, alpha, cell
        )

    def deferred_checks(self) -> list[DeferredCheck]:
        """The ring check, latched on the device instead of read (``training.deferred``)."""
        self.deferred_overflow = DeferredCheck(self.overflow_error)
        return [self.deferred_overflow]


class PGPolicy:
    """Executor policy of a pure-PG graph: each push samples from the node's policy.

    Args:
        learner: the HPGRL learner (its ``select`` scores the choices).
        rng: random numbers for the rows.
        greedy: act on the policies' modes and score nothing (evaluation).
    """

    def __init__(self, learner: HPGRLLearner, rng, greedy: bool = False) -> None:
        self.learner = learner
        self.rng = rng
        self.greedy = greedy
        self.draws = LevelDraws(rng, learner.graph, learner.n_uniforms)

    def new_step(self) -> None:
        """Take this step's draw (``n_uniforms`` per level, read when asked)."""
        self.draws.new_step()

    def select(self, inst, ctx, available, step, push) -> Choice:
        """The choices of the ``push``-th push of the step."""
        u = self.draws.level(push)
        return self.learner.select(inst, ctx, available, u, self.greedy, step)

    def select_rows(self, inst, ctx, available, step, push, rows) -> Choice:
        """``select`` for the batch rows ``rows [R]`` only (their numbers alone are drawn)."""
        u = self.draws.level_rows(push, rows)
        return self.learner.select(inst, ctx, available, u, self.greedy, step, rows)


class ActorCriticLearner(HPGRLLearner):
    """Flat actor-critic (Section 5.3, after Konda 2002) on a one-level continuous-action graph.

    The actor is the root's tile-coded Gaussian (as flat PGRL); the critic is a tile-coded
    ``Q(s, a)`` over the root's features and the action, learned by SARSA(0)::

        Q(s, a) <- Q(s, a) + alpha_c [r + Q(s', a') - Q(s, a)]      (r at a terminal s')
        theta  <- theta + beta [Q(s, a) - Q(s, a_mean(s))] grad log mu(a|s)

    ``Q(s, a_mean)`` (the critic at the actor's mean action) is a state-dependent baseline: the
    text's critic is not Konda's compatible one, whose values have zero mean over actions.

    Args:
        graph: a graph whose root has a single continuous primitive child and features.
        n_learners: population size ``P``.
        coder: actor tile coder (root features).
        critic_coder: tile coder over ``[features, action]``.
        config: the actor's options (``alpha`` is ``beta``).
        critic_alpha: the critic's step size.
        feature_reward: as for ``HPGRLLearner``.
    """

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        coder: TileCoder,
        critic_coder: TileCoder,
        config: PGConfig | None = None,
        critic_alpha: float | Schedule = 0.1,
        feature_reward: Mapping[str, FeatureReward] | None = None,
    ) -> None:
        config = config or PGConfig()
        config = PGConfig(**{**config.__dict__, "trace_len": 1, "online": True, "value_rate": 0})
        super().__init__(graph, n_learners, config, [graph.root_name], coder, feature_reward)
        if not self.has_gauss:
            raise GraphError("ActorCriticLearner needs a root with one continuous child")
        self.actor = self.heads[graph.root_name]
        check_step_size(self, "critic_alpha", critic_alpha, one_for_all=True)
        self.critic_alpha = as_schedule(critic_alpha)
        self.critics = nn.ModuleDict(
            {graph.root_name: TileValueHead(graph.root_name, critic_coder, n_learners)}
        )
        self.critic = self.critics[graph.root_name]

    def _q_tiles(self, learner, features, action) -> torch.Tensor:
        dims = self.critic.coder.resolution.numel() - 1
        return self.critic.tiles(learner, torch.cat([features[:, :dims], action.reshape(-1, 1)], 1))

    def update(self, batch, step: int) -> None:
        """Critic SARSA(0) on the previous step, actor step on this one."""
        level, prim = batch[LEVEL], batch[PRIMITIVE]
        b = batch.batch_size[0]
        rows = self._row_state(b, self.theta.device)
        critic = self.critic
        none = critic.w.numel() - 1  # the critic's sentinel
        if "prev_tiles" not in rows:
            t, dev = critic.coder.n_tilings, critic.w.device
            rows["prev_tiles"] = torch.full((b, t), none, dtype=torch.long, device=dev)
            rows["prev_r"] = torch.zeros(b, device=dev)
            rows["has_prev"] = torch.zeros(b, dtype=torch.bool, device=dev)
        depths = self.depths[:1]
        valid = level["valid"][:, 0]
        r = self.rewards(batch, level["node"].index_select(1, depths), depths)[:, 0]
        learner, feats = batch["learner"], level["features"][:, 0]
        tiles = torch.where(valid[:, None], self._q_tiles(learner, feats, prim["action"]), none)
        q = critic.value(tiles)
        # actor: baseline = the critic at the actor's mean action
        _, mean = self.actor.mean(self.theta, learner * self.total, feats)
        actor = self.actor
        q_mean = critic.value(self._q_tiles(learner, feats, squash(mean, *actor.range())))
        advantage = torch.where(valid, q - q_mean, 0.0)
        slot0 = (
            torch.where(valid[:, None], level["score_index"][:, 0], self.sentinel),
            level["score_value"][:, 0],
        )
        alpha = self.alpha(step)
        self.theta.index_add_(
            0, slot0[0].reshape(-1), (alpha * advantage[:, None] * slot0[1]).reshape(-1)
        )
        self.theta[-1:].zero_()
        # critic: the previous step bootstraps from Q(s, a) of this one; a terminal step at once
        c_alpha = self.critic_alpha(step)
        prev = rows["has_prev"] & valid
        delta_prev = torch.where(prev, rows["prev_r"] + q - critic.value(rows["prev_tiles"]), 0.0)
        terminal = level["terminal"][:, 0] & valid
        delta_now = torch.where(terminal, r - q, 0.0)
        critic.add(rows["prev_tiles"], c_alpha * delta_prev)
        critic.add(tiles, c_alpha * delta_now)
        self.record_td(learner, level["node"][:, 0], delta_prev, prev)
        keep = valid & ~terminal & ~level["truncated"][:, 0]
        rows["prev_tiles"] = torch.where(keep[:, None], tiles, none)
        rows["prev_r"] = r
        rows["has_prev"] = keep
