"""The ship's learners, their hyperparameters and progress monitor (Section 5.3, Figs 5.7-5.11)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from agents.ship import (
    DIRECTION_NODES,
    LOW_LEVEL_GUARD,
    SUBTASK_NAMES,
    SUBTASK_OF_DIRECTION,
    direction_groups,
    flat_tile_coder,
    local_success,
    low_level_feature_rewards,
    low_level_tile_coder,
)
from envs.ship import MAX_TURN, SIZE, ShipSteeringEnv
from hrl_torch.execution.transitions import LEVEL, PRIMITIVE
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.learners.hybrid import HybridLearner
from hrl_torch.learners.pg import ActorCriticLearner, HPGRLLearner, PGConfig
from hrl_torch.learners.progress import EpisodeBins
from hrl_torch.learners.q_lambda import QLambdaLearner
from hrl_torch.modules.exploration import TriggeredEpsilon
from hrl_torch.modules.tiles import TileCoder

#: the rudder's range, the env's ``action_bounds`` (+-15 deg/s), given explicitly: a PG node's
#: range is never a silent default (``hrl_torch.learners.action_range``)
RUDDER = {"action_low": -MAX_TURN, "action_high": MAX_TURN}


# ---------------------------------------------------------------------- progress (Figures 5.7-5.11)
class ShipMonitor(nn.Module):
    """Progress per learner, in blocks of 1000 (``EpisodeBins``).

    Per episode: gate success, primitive steps and low-level calls; per execution of each
    low-level subtask: its success.

    Also Section 5.3's epsilon trigger: a learner fires once the last completed block of 1000
    executions of *each* low-level subtask succeeded at least ``trigger_rate`` of the time (the
    text says "until the performances of low-level subtasks reach a certain level").

    Works on the hierarchy (low-level executions at depth 1) and on the flat graph.

    Args:
        graph: ``ship_hierarchy()`` or ``flat_graph()``.
        n_learners: population size ``P``.
        n_bins: blocks of 1000 episodes (and of 1000 executions) kept.
        trigger_rate: low-level success rate that starts the epsilon decay.
        count_cut: count the executions the episode's end cut short (the gate passed, the
            square left, the time limit) as low-level failures (default); ``False`` counts
            only those that ended on their own (local success, local failure, the guard).
    """

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        n_bins: int = 100,
        trigger_rate: float = 0.8,
        count_cut: bool = True,
    ) -> None:
        super().__init__()
        self.count_cut = count_cut
        self.hierarchical = graph.max_levels > 2
        kind = torch.full((graph.n_nodes,), -1, dtype=torch.long)
        for k, name in enumerate(DIRECTION_NODES):
            if name in graph.index:
                kind[graph.index[name]] = int(SUBTASK_OF_DIRECTION[k])
        self.register_buffer("kind_of_node", kind, persistent=False)
        self.trigger_rate = float(trigger_rate)
        self.episodes = EpisodeBins(
            n_learners, 1000, n_bins, ["success", "steps", "calls", "gate_steps"]
        )
        self.low = nn.ModuleList(
            EpisodeBins(n_learners, 1000, 4 * n_bins, ["success"]) for _ in SUBTASK_NAMES
        )
        self._rows: dict[str, torch.Tensor] = {}

    def get_extra_state(self) -> dict:
        """Steps and calls of the running episodes (checkpoints)."""
        return {k: v.clone() for k, v in self._rows.items()}

    def set_extra_state(self, state: dict) -> None:
        """Restore ``get_extra_state``."""
        self._rows = {k: v.clone() for k, v in state.items()}

    def observe(self, batch) -> tuple[torch.Tensor, torch.Tensor]:
        """Count one transition batch; return episodes ended ``[P]`` and the trigger ``[P]``."""
        level, prim = batch[LEVEL], batch[PRIMITIVE]
        b, p = batch.batch_size[0], self.episodes.events.shape[0]
        if "steps" not in self._rows or self._rows["steps"].shape[0] != b:
            zeros = torch.zeros(b, device=prim["valid"].device)
            self._rows = {"steps": zeros, "calls": zeros.clone()}
        rows = self._rows
        rows["steps"] += prim["valid"]
        root = level["valid"][:, 0]
        ended = root & (level["terminal"][:, 0] | level["truncated"][:, 0])
        if self.hierarchical:
            rows["calls"] += root
            executed = root & level["child_done"][:, 0]
            if not self.count_cut:  # (an execution the episode's end cut short)
                executed = executed & ~ended
            kind = self.kind_of_node[level["node"][:, 1]]
            local = level["next_features"][:, 1]
            success = local_success(local, kind.clamp_min(0))
            for t, bins in enumerate(self.low):
                bins.add(executed & (kind == t), {"success": success})
        gate = batch["obs", "success"] & ended
        self.episodes.add(
            ended,
            {
                "success": gate,
                "steps": rows["steps"],
                "calls": rows["calls"],
                "gate_steps": rows["steps"] * gate,
            },
        )
        rows["steps"] = rows["steps"].masked_fill(ended, 0.0)
        rows["calls"] = rows["calls"].masked_fill(ended, 0.0)
        return ended.view(p, -1).sum(1), self._trigger()

    def _trigger(self) -> torch.Tensor:
        """Each low-level subtask's last completed block succeeded ``trigger_rate`` of the time.

        Both subtasks at once: only the last completed block's sums are read (its count is the
        block size, so its mean is what ``EpisodeBins.block_means`` gives).
        """
        done = torch.stack([bins.completed() for bins in self.low])  # [2, P]
        sums = torch.stack([bins.sums for bins in self.low])  # [2, 2, P, n_bins + 1]
        last = (done - 1).clamp_min(0)[:, None, :, None].expand(-1, 2, -1, 1)
        count, successes = sums.gather(3, last).squeeze(3).unbind(1)
        rate = successes / count.clamp_min(1)
        fired = ((done > 0) & (rate >= self.trigger_rate)).all(0)
        return fired & self.hierarchical


# ---------------------------------------------------------------------- learners and experiments
@dataclass(frozen=True)
class ShipHyperparams:
    """Hyperparameters of the ship experiments (Section 5.3; ours where the text is silent).

    Attributes:
        q_alpha: the root's Q(lambda) step size (text: 0.1).
        lam: its lambda (text: 0.9).
        epsilon: its initial epsilon (text: 0.1), divided by ``epsilon_factor`` every
            ``epsilon_every`` episodes once the low-level subtasks succeed ``trigger_rate`` of the
            time (text: 1.01, 50, "a certain level").
        epsilon_factor: see ``epsilon``.
        epsilon_every: see ``epsilon``.
        trigger_rate: see ``epsilon`` (ours).
        pg_alpha: step size of the low-level HPGRL subtasks (ours).
        flat_alpha: step size of flat PGRL (ours).
        actor_alpha: step size of the actor-critic's actor (ours).
        critic_alpha: the actor-critic's critic step size (ours).
        sigma: the Gaussian policies' standard deviation before the squash (text: 1).
        online: HPGRL updates every step (Algorithm 3 line 16) or once per renewal cycle.
        pg_beta: the low-level eligibility discount (1: Equation 5.3; ours).
        pg_baseline: step size of the low-level reward-to-go baseline (0: none; ours).
        out_of_bounds_reward: the root's reward for leaving the square (text: none).
    """

    q_alpha: float = 0.1
    lam: float = 0.9
    epsilon: float = 0.1
    epsilon_factor: float = 1.01
    epsilon_every: int = 50
    trigger_rate: float = 0.6
    pg_alpha: float = 0.02
    flat_alpha: float = 0.005
    actor_alpha: float = 0.005
    critic_alpha: float = 0.1
    sigma: float = 1.0
    online: bool = False
    pg_beta: float = 0.95
    pg_baseline: float = 0.0
    out_of_bounds_reward: float = -1000.0


PARAMS = ShipHyperparams()


def make_hybrid(
    graph: TaskGraph, n_learners: int, params: ShipHyperparams = PARAMS
) -> HybridLearner:
    """The hierarchical hybrid: Q(lambda) at the root, HPGRL at the two low-level subtasks."""
    value = QLambdaLearner(graph, n_learners, params.q_alpha, params.lam, nodes=["Root"])
    pg = HPGRLLearner(
        graph,
        n_learners,
        PGConfig(
            alpha=params.pg_alpha,
            sigma=params.sigma,
            online=params.online,
            beta=params.pg_beta,
            baseline=params.pg_baseline,
            trace_len=LOW_LEVEL_GUARD,
            value_rate=0.0,  # (this reading has no state baseline)
            **RUDDER,
        ),
        direction_groups(),
        low_level_tile_coder(),
        low_level_feature_rewards(),
    )
    epsilon = TriggeredEpsilon(
        n_learners, params.epsilon, params.epsilon_factor, params.epsilon_every
    )
    monitor = ShipMonitor(graph, n_learners, trigger_rate=params.trigger_rate)
    return HybridLearner(graph, n_learners, value, pg, epsilon, monitor)


class _Monitored:
    """Mixin: a flat learner that also feeds a ``ShipMonitor`` (same metrics as the hybrid)."""

    def update(self, batch, step: int) -> None:
        super().update(batch, step)
        self.monitor.observe(batch)


class FlatPGRL(_Monitored, HPGRLLearner):
    """Flat PGRL (Equation 5.3 over whole episodes) with the ship's progress monitor."""


class ShipActorCritic(_Monitored, ActorCriticLearner):
    """The flat actor-critic with the ship's progress monitor."""


def make_flat_pg(graph: TaskGraph, n_learners: int, params: ShipHyperparams = PARAMS) -> FlatPGRL:
    """Flat PGRL: one Gaussian over 9 tilings of 20 x 20 x 36 x 5 of the global state."""
    config = PGConfig(
        alpha=params.flat_alpha,
        sigma=params.sigma,
        online=params.online,
        trace_len=1000,
        value_rate=0.0,
        **RUDDER,
    )
    return flat_pg_learner(graph, n_learners, config)


def flat_pg_learner(graph: TaskGraph, n_learners: int, config: PGConfig) -> FlatPGRL:
    """Flat PGRL with ``config`` on ``flat_tile_coder``'s features, watched by a ``ShipMonitor``."""
    learner = FlatPGRL(graph, n_learners, config, ["Root"], flat_tile_coder())
    learner.monitor = ShipMonitor(graph, n_learners)
    return learner


def critic_tile_coder() -> TileCoder:
    """The actor-critic's critic: 9 tilings of 5 x 5 x 36 x 5 x 30 over (state, action)."""
    return TileCoder(
        low=[0.0, 0.0, -180.0, -MAX_TURN, -MAX_TURN],
        high=[SIZE, SIZE, 180.0, MAX_TURN, MAX_TURN],
        resolution=[5, 5, 36, 5, 30],
        n_tilings=9,
        wrap=[False, False, True, False, False],
    )


def make_actor_critic(
    graph: TaskGraph, n_learners: int, params: ShipHyperparams = PARAMS
) -> ShipActorCritic:
    """Actor-critic (Konda): flat PGRL's actor, a 5-D tile-coded Q(s, a) critic."""
    actor = PGConfig(alpha=params.actor_alpha, sigma=params.sigma, **RUDDER)
    return actor_critic_learner(graph, n_learners, actor, params.critic_alpha)


def actor_critic_learner(
    graph: TaskGraph, n_learners: int, actor: PGConfig, critic_alpha: float
) -> ShipActorCritic:
    """``ShipActorCritic`` with the actor's ``PGConfig``, watched by a ``ShipMonitor``."""
    learner = ShipActorCritic(
        graph, n_learners, flat_tile_coder(), critic_tile_coder(), actor, critic_alpha
    )
    learner.monitor = ShipMonitor(graph, n_learners)
    return learner


def make_env(seeds, envs_per_learner: int, backend: str = "torch") -> ShipSteeringEnv:
    """Ship steering for ``seeds`` (0.6 s control interval, 1000-step limit)."""
    if backend != "torch":
        raise ValueError(f"unknown backend {backend!r}")
    return ShipSteeringEnv(seeds, envs_per_learner)
