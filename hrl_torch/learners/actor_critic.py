"""Flat actor-critic (Section 5.3, after Konda 2002) on a one-level continuous-action graph.

Split from ``pg.py`` (its length); ``hrl_torch.learners.pg.ActorCriticLearner`` still names it.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import nn

from hrl_torch.execution.transitions import LEVEL, PRIMITIVE
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.learners.pg import FeatureReward, HPGRLLearner, PGConfig
from hrl_torch.learners.validate import check_step_size
from hrl_torch.modules.exploration import Schedule, as_schedule
from hrl_torch.modules.heads import TileValueHead
from hrl_torch.modules.policies import squash
from hrl_torch.modules.tiles import TileCoder

__all__ = ["ActorCriticLearner"]


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
