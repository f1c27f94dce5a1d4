"""Ship steering as Section 5.3 sets it: the ``-text`` variants of the hybrid and the baselines.

Beside today's ``hybrid``, ``flat-pg`` and ``actor-critic`` (``agents/ship.py``, unchanged), these
follow the text where today's variants deviate:

- **Low-level subtasks learned first on their own** (the text: "we successfully applied a flat
  policy gradient algorithm to the simplified versions of this problem shown in Figure 5.5 ...
  Using this prior knowledge, we decompose the problem"). Each subtask is the simplified task of
  Figure 5.5 (``ShipSubtaskEnv``: its local start, a uniformly random heading and turning rate,
  success within 10 m of its goal, failure outside the 150 m box), learned by flat PGRL until
  every seed succeeds in ``pretrain_target`` of a block of 1000 episodes (its own learning
  curve), then handed to the hybrid, which keeps learning it.
- **Algorithm 3 lines 11-16 with** ``beta = 1`` (Equation 5.3) and a decaying step size
  ``alpha_k = alpha_0 tau / (tau + k)`` (``Harmonic``: Assumptions 5.3 and 5.4, ``sum alpha_k =
  inf``, ``sum alpha_k^2 < inf``). Flat PGRL updates every step (line 16). The low level applies
  the invocation's sum at the renewal less a state baseline, ``sum_n (R_n - V(s_n)) g_n``
  (``value_baseline_traces``), on a CMAC of the heading error to its goal
  (``BearingTileCoder``): with the rule as written it stayed below 80% success (issue 26,
  docs/reproduction.md).
- **Epsilon** 0.1, unchanged until the low level "reaches a certain level" (both subtasks
  succeed in ``trigger_rate`` of their last 1000 executions that ended on their own), then
  divided by 1.01 every 50 episodes (``TriggeredEpsilon``).
- **A few streams per seed** (``STREAMS`` envs per learner, their updates summed).
- **Out-of-square penalty** ``out_of_bounds_reward``: the smallest that removes the incentive to
  leave (``leave_penalty``; see docs/reproduction.md). Flat PGRL and actor-critic get the same
  rewards and the same Algorithm-3 step rule, so the text's ~60% is compared like for like.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from agents.ship import (
    LOCAL_GOAL,
    LOCAL_START,
    LOW_LEVEL_GUARD,
    LOW_LEVEL_REWARDS,
    SUBTASK_NAMES,
    direction_groups,
    local_failure,
    local_success,
    low_level_feature_rewards,
    low_level_tile_coder,
)
from agents.ship import bearing as goal_bearing
from agents.ship_learners import (
    RUDDER,
    FlatPGRL,
    ShipActorCritic,
    ShipMonitor,
    actor_critic_learner,
    flat_pg_learner,
)
from envs.ship import MAX_TURN, ShipSteeringEnv, wrap_degrees
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.learners.hybrid import HybridLearner
from hrl_torch.learners.pg import HPGRLLearner, PGConfig
from hrl_torch.learners.pg_traces import value_baseline_traces
from hrl_torch.learners.q_lambda import QLambdaLearner
from hrl_torch.modules.exploration import TriggeredEpsilon
from hrl_torch.modules.policies import TileGaussianPolicyHead
from hrl_torch.modules.tiles import TileCoder

#: envs per learner of the -text variants (see docs/reproduction.md for what it changes)
STREAMS = 64


@dataclass(frozen=True)
class Harmonic:
    """Step size ``alpha_k = start * tau / (tau + k)`` over env steps ``k`` per learner.

    Non-increasing, ``sum alpha_k = inf`` and ``sum alpha_k^2 < inf`` (Assumption 5.3), and
    Assumption 5.4 holds with ``p = 2``. ``float()`` is its largest value (range checks).
    """

    start: float
    tau: float

    def __post_init__(self) -> None:
        if not (self.start > 0 and self.tau > 0):
            raise ValueError(f"Harmonic needs start > 0 and tau > 0, got {self.start}, {self.tau}")

    def __call__(self, step: int | torch.Tensor) -> float | torch.Tensor:
        """Value at ``step``; on a device clock (a tensor) a float64 tensor, read nowhere."""
        if isinstance(step, torch.Tensor):
            denominator = self.tau + step.clamp(min=0).double()
            return denominator.new_full((), self.start * self.tau) / denominator  # (exact /)
        return self.start * self.tau / (self.tau + max(step, 0))

    def __float__(self) -> float:
        return self.start


@dataclass(frozen=True)
class TextParams:
    """Hyperparameters of the ``-text`` variants (text: Section 5.3; ours where it is silent).

    Attributes:
        q_alpha, lam, epsilon, epsilon_factor, epsilon_every: the root's Q(lambda) (text).
        trigger_rate: low-level success that starts the epsilon decay ("a certain level").
        pg_alpha, pg_tau: the low-level ``Harmonic`` step size (ours).
        flat_alpha, flat_tau: flat PGRL's and the actor's ``Harmonic`` step size (ours).
        critic_alpha: the actor-critic's critic step size (ours).
        sigma: Gaussian width before the squash (text: 1).
        pg_beta, pg_online: the low level's eligibility discount and update timing (text: 1,
            every step; other values are the family's other members, for comparison only).
        pg_baseline, pg_init: the low level's ``PGConfig.baseline`` and ``init`` (ours).
        pg_bound: after each update the low level's parameters are projected onto
            ``[-pg_bound, pg_bound]`` (ours; 0: none). ``A`` is their tile mean, so the mean
            action stays where the sigmoid still responds to ``u``.
        pg_value_rate: step size of the low level's state baseline ``V`` (ours; 0: none;
            ``value_baseline_traces``).
        features: the low level's CMAC input: ``"state"`` (x, y, theta, theta_dot) or
            ``"bearing"`` (x, y, theta - theta_hat, theta_dot), ``theta_hat`` the bearing to the
            local goal (ours; the same 5 x 5 x 36 x 5 tiles, ``BearingTileCoder``).
        out_of_bounds_reward: the root's reward for leaving the square (ours, see module doc).
        pretrain_target: low-level success per 1000 episodes the pretraining stops at.
        pretrain_episodes: cap on pretraining episodes per subtask and seed.
        pretrain_envs: envs per learner of the pretraining.
    """

    q_alpha: float = 0.1
    lam: float = 0.9
    epsilon: float = 0.1
    epsilon_factor: float = 1.01
    epsilon_every: int = 50
    trigger_rate: float = 0.9
    pg_alpha: float = 0.03
    pg_tau: float = 2_000_000.0
    flat_alpha: float = 0.005
    flat_tau: float = 2_000_000.0
    critic_alpha: float = 0.1
    sigma: float = 1.0
    pg_beta: float = 1.0
    pg_online: bool = False
    pg_baseline: float = 0.0
    pg_init: float = 0.0
    pg_bound: float = 0.0
    pg_value_rate: float = 0.1
    features: str = "bearing"
    out_of_bounds_reward: float = -400.0
    pretrain_target: float = 0.98
    pretrain_episodes: int = 40_000
    pretrain_envs: int = 256


TEXT = TextParams()
FEATURES = ("state", "bearing")


class BearingTileCoder(TileCoder):
    """The low level's CMAC over (x, y, theta - theta_hat, theta_dot) of the local state.

    ``theta_hat`` is the bearing from (x, y) to ``goal``, the heading error wrapped to
    [-180, 180); the grid is ``low_level_tile_coder``'s (9 tilings of 5 x 5 x 36 x 5). The
    heading that points at the goal is one column of tiles at every position, so what is
    learned about turning toward the goal at one position holds at the others.
    """

    def __init__(self, goal: torch.Tensor) -> None:
        plain = low_level_tile_coder()
        super().__init__(
            plain.low.tolist(),
            plain.high.tolist(),
            plain.resolution.tolist(),
            plain.n_tilings,
            plain.wrap.tolist(),
        )
        self.register_buffer("goal", torch.as_tensor(goal, dtype=torch.float32).reshape(2))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Active tiles of local states ``x [..., 4]``: ``[..., T]`` long."""
        flat = x.reshape(-1, 4).float()
        goal = self.goal.to(flat.device).expand(flat.shape[0], 2)
        error = wrap_degrees(flat[:, 2] - goal_bearing(flat[:, :2], goal))
        mapped = torch.cat([flat[:, :2], error[:, None], flat[:, 3:]], dim=-1)
        return super().forward(mapped.view(*x.shape[:-1], 4))


def subtask_coder(subtask: int, params: TextParams = TEXT) -> TileCoder:
    """The CMAC of low-level ``subtask`` (``params.features``)."""
    if params.features == "state":
        return low_level_tile_coder()
    if params.features == "bearing":
        return BearingTileCoder(LOCAL_GOAL[subtask])
    raise ValueError(f"features must be one of {FEATURES}, got {params.features!r}")


def subtask_heads(params: TextParams = TEXT) -> dict[str, TileGaussianPolicyHead]:
    """One tile-coded Gaussian per low-level group, on its subtask's CMAC.

    The plain CMAC is one coder for both groups (one ``act`` call, as before ``features``).
    """
    shared = low_level_tile_coder() if params.features == "state" else None
    return {
        name: TileGaussianPolicyHead(
            name, shared or subtask_coder(k, params), params.sigma, -MAX_TURN, MAX_TURN
        )
        for k, name in enumerate(SUBTASK_NAMES)
    }


def low_level_config(params: TextParams = TEXT) -> PGConfig:
    """Algorithm 3 lines 11-16 (as written by default: every step, ``beta = 1``), decaying step."""
    return PGConfig(
        alpha=Harmonic(params.pg_alpha, params.pg_tau),
        sigma=params.sigma,
        online=params.pg_online,
        beta=params.pg_beta,
        trace_len=LOW_LEVEL_GUARD,
        init=params.pg_init,
        baseline=params.pg_baseline,
        value_rate=0.0,  # (its state baseline is _LowLevelRule's, set by ``configure``)
        **RUDDER,
    )


# ---------------------------------------------------------------------- Figure 5.5 subtasks
class ShipSubtaskEnv(ShipSteeringEnv):
    """The simplified task of Figure 5.5 in the subtask's local frame.

    Starts at ``LOCAL_START[subtask]`` with a uniformly random heading and turning rate; ends
    (after a whole control step, as the hierarchy's subtasks do) with success within 10 m of the
    local goal, or failure outside ``0 <= x, y <= 150``; truncated after ``LOW_LEVEL_GUARD``
    steps. Reward -1 per step; ``success`` is local success.

    Args:
        subtask: ``DIAGONAL`` (0) or ``STRAIGHT`` (1).
        seeds, envs_per_learner: as ``ShipSteeringEnv``.
    """

    def __init__(self, subtask: int, seeds=(0,), envs_per_learner: int = 1, **kw) -> None:
        if subtask not in (0, 1):
            raise ValueError(f"subtask must be 0 (diagonal) or 1 (straight), got {subtask}")
        kw.setdefault("max_episode_steps", LOW_LEVEL_GUARD)
        super().__init__(seeds, envs_per_learner, **kw)
        self.subtask = subtask
        self._kind = torch.full((self.batch_size,), subtask, dtype=torch.long)

    def _reset_rows(self, mask: torch.Tensor) -> None:
        super()._reset_rows(mask)
        start = LOCAL_START[self.subtask].to(self.device)
        self.state[:, :2] = torch.where(mask[:, None], start, self.state[:, :2])

    def _step_all(self, action: torch.Tensor):
        reward, duration, _ = super()._step_all(action)  # the 150 m box lies inside the square
        success = local_success(self.state, self._kind.to(self.device))
        self.success = success
        return reward, duration, success | local_failure(self.state)


class _LowLevelRule:
    """Mixin of the ``-text`` low level: an optional state baseline and parameter bound.

    ``value_rate > 0``: line 16 at the renewal less ``V(s_n)`` (``value_baseline_traces``;
    needs ``online=False``, which sums to the same update per cycle as every step, and
    ``baseline=0``). ``bound > 0``: after every update the parameters are projected onto
    ``[-bound, bound]`` (projected stochastic approximation).
    """

    bound: float = 0.0
    value_rate: float = 0.0

    def __init__(self, *args, **kw) -> None:
        super().__init__(*args, **kw)
        self.register_buffer("value_table", torch.zeros_like(self.theta))

    def configure(self, params: TextParams) -> None:
        """Take ``pg_bound`` and ``pg_value_rate`` from ``params``."""
        cfg = self.config
        if params.pg_value_rate and (cfg.online or cfg.frozen or cfg.baseline):
            raise ValueError("pg_value_rate needs pg_online=False, no pg_baseline, not frozen")
        if params.pg_value_rate < 0 or params.pg_bound < 0:
            raise ValueError("pg_value_rate and pg_bound must be >= 0")
        self.bound, self.value_rate = params.pg_bound, params.pg_value_rate

    def apply_traces(self, rows, pairs: torch.Tensor, alpha, cell: torch.Tensor) -> None:
        if not self.value_rate:
            return super().apply_traces(rows, pairs, alpha, cell)
        value_baseline_traces(self, rows, pairs, alpha, cell)

    def update(self, batch, step: int) -> None:
        super().update(batch, step)
        if self.bound:
            self.theta.clamp_(-self.bound, self.bound)  # (the sentinel 0 stays 0)


class SubtaskPGRL(_LowLevelRule, FlatPGRL):
    """Flat PGRL of one low-level subtask (Figure 5.5) with the ``-text`` low-level rule."""


class LowLevelPG(_LowLevelRule, HPGRLLearner):
    """The hybrid's low level (HPGRL over the eight directions) with the same rule."""


def group_block(learner, tensor: torch.Tensor, group: str, p: int) -> torch.Tensor:
    """Learner ``p``'s block of group ``group`` in a tensor laid out like ``learner.theta``."""
    k, head = learner.group_names.index(group), learner.heads[group]
    flat = tensor[: learner.sentinel].view(learner.n_learners, learner.total)
    start = int(learner.params.offset[k])
    return flat[p, start : start + head.n_states * head.n_cols]


def subtask_graph() -> TaskGraph:
    """One PG root steering on the local state (the flat PGRL of the text's Figure 5.5 runs)."""
    root = Subtask("Root", ["Turn"], features=lambda o: o["observation"], n_features=4)
    return TaskGraph("Root", [root, Primitive("Turn", action_dim=1)])


def make_subtask_learner(subtask: int, n_learners: int, params: TextParams = TEXT) -> FlatPGRL:
    """Flat PGRL of one subtask: its group's CMAC and internal rewards, the text's step rule."""
    graph = subtask_graph()
    name = SUBTASK_NAMES[subtask]
    learner = SubtaskPGRL(
        graph,
        n_learners,
        low_level_config(params),
        {"Root": name},
        subtask_coder(subtask, params),
        {"Root": LOW_LEVEL_REWARDS[subtask]},
        heads={name: subtask_heads(params)[name]},
    )
    learner.monitor = ShipMonitor(graph, n_learners, n_bins=400)
    learner.configure(params)
    return learner


def _subtask_done(monitor: ShipMonitor, target: float, cap: int) -> bool:
    """Every learner's last block of 1000 episodes reached ``target``, or hit ``cap`` episodes."""
    bins = monitor.episodes
    done = bins.completed()
    last = (done - 1).clamp_min(0)
    rate = bins.sums[1].gather(1, last[:, None]).squeeze(1) / bins.size
    return bool((((done > 0) & (rate >= target)) | (bins.events >= cap)).all())


def pretrain_subtask(subtask: int, seeds, params: TextParams = TEXT, on_step=None):
    """Flat PGRL on Figure 5.5's simplified ``subtask`` until ``pretrain_target`` (or the cap).

    Returns the trained learner and ``{"episodes", "env_steps", "seconds", "success_per_block",
    "steps_per_block"}`` (per learner; blocks of 1000 episodes with exploration).
    """
    from hrl_torch.common.rng import BatchRNG
    from hrl_torch.modules.exploration import Greedy
    from hrl_torch.training.agent import HierarchicalAgent
    from hrl_torch.training.collector import collect

    e = params.pretrain_envs
    learner = make_subtask_learner(subtask, len(seeds), params)
    offset = 7919 * (subtask + 1)  # streams apart from the hybrid's own
    env = ShipSubtaskEnv(subtask, [s + offset for s in seeds], e)
    rng = BatchRNG([s + offset for s in seeds], e, "pretrain")
    agent = HierarchicalAgent(learner.graph, learner, Greedy(), rng, e)
    monitor = learner.monitor
    stats = collect(
        env,
        agent,
        until=lambda: _subtask_done(monitor, params.pretrain_target, params.pretrain_episodes),
        on_step=on_step,
    )
    means = monitor.episodes.block_means()
    full = monitor.episodes.sums[0, :, : monitor.episodes.n_bins] >= monitor.episodes.size
    curve = {k: torch.where(full, means[k], torch.nan).tolist() for k in ("success", "steps")}
    return learner, {
        "episodes": monitor.episodes.events.tolist(),
        "env_steps": stats["env_steps"],
        "seconds": stats["seconds"],
        "success_per_block": curve["success"],
        "steps_per_block": curve["steps"],
    }


# ---------------------------------------------------------------------- the -text learners
class HybridTextLearner(HybridLearner):
    """The hybrid whose low level is first learned on Figure 5.5's simplified tasks.

    ``pretrain()`` runs ``pretrain_subtask`` for both subtasks (learner ``p`` on seed ``p``) and
    copies each learner's policy into its group (``pretrained`` records it in checkpoints;
    ``pretrain_stats`` keeps its curves). ``scripts/fig_5_7_to_5_12_ship.py`` calls it before
    training; a run that does not (``hrl-torch train``, the generic tests) starts the low level
    from zero inside the hierarchy, as today's ``hybrid`` does.
    """

    def __init__(self, *args, params: TextParams = TEXT, **kw) -> None:
        super().__init__(*args, **kw)
        self.params = params
        self.register_buffer("pretrained", torch.zeros((), dtype=torch.bool))
        self.pretrain_stats: dict[str, dict] = {}

    def pretrain(self, seeds=None, on_step=None) -> dict[str, dict]:
        """Learn both low-level subtasks alone, then hand them to the hierarchy."""
        seeds = list(range(self.n_learners)) if seeds is None else list(seeds)
        for subtask, name in enumerate(SUBTASK_NAMES):
            sub, stats = pretrain_subtask(subtask, seeds, self.params, on_step)
            for p in range(self.n_learners):
                self.pg.group_view(name, p).copy_(sub.group_view(name, p))
                group_block(self.pg, self.pg.value_table, name, p).copy_(
                    group_block(sub, sub.value_table, name, p)
                )
            self.pretrain_stats[name] = stats
        self.pretrained.fill_(True)
        return self.pretrain_stats


def make_hybrid_text(
    graph: TaskGraph, n_learners: int, params: TextParams = TEXT
) -> HybridTextLearner:
    """Q(lambda) root (text's settings) over the pretrained HPGRL subtasks (Algorithm 3)."""
    value = QLambdaLearner(graph, n_learners, params.q_alpha, params.lam, nodes=["Root"])
    pg = LowLevelPG(
        graph,
        n_learners,
        low_level_config(params),
        direction_groups(),
        low_level_tile_coder(),
        low_level_feature_rewards(),
        heads=subtask_heads(params),
    )
    pg.configure(params)
    epsilon = TriggeredEpsilon(
        n_learners, params.epsilon, params.epsilon_factor, params.epsilon_every
    )
    monitor = ShipMonitor(graph, n_learners, trigger_rate=params.trigger_rate, count_cut=False)
    return HybridTextLearner(graph, n_learners, value, pg, epsilon, monitor, params=params)


def make_flat_pg_text(graph: TaskGraph, n_learners: int, params: TextParams = TEXT) -> FlatPGRL:
    """Flat PGRL with Equation 5.3 as written: every step, ``beta = 1``, decaying step size."""
    config = PGConfig(
        alpha=Harmonic(params.flat_alpha, params.flat_tau),
        sigma=params.sigma,
        online=True,
        beta=1.0,
        trace_len=1000,
        **RUDDER,
    )
    return flat_pg_learner(graph, n_learners, config)


def make_actor_critic_text(
    graph: TaskGraph, n_learners: int, params: TextParams = TEXT
) -> ShipActorCritic:
    """Today's actor-critic with the decaying actor step size of the other -text variants."""
    actor = PGConfig(
        alpha=Harmonic(params.flat_alpha, params.flat_tau), sigma=params.sigma, **RUDDER
    )
    return actor_critic_learner(graph, n_learners, actor, params.critic_alpha)


def with_overrides(**changes) -> TextParams:
    """``TEXT`` with some fields changed (the scripts' ``--set``)."""
    return replace(TEXT, **changes)
