"""Designer's knowledge for ship steering (Section 5.3, Figures 5.5 and 5.6), as batched functions.

High level (Figure 5.6): the root sees only (x, y), discretised into a 20 x 20 grid of 50 m
cells (400 states, ``grid_state``), and chooses one of eight directions, numbered clockwise from
north like compass headings ``45 * k`` degrees::

    k:        0   1    2   3    4   5    6   7
    heading:  N   NE   E   SE   S   SW   W   NW      (theta: 0 = +y, 90 = +x)
    subtask:  S   D    S   D    S   D    S   D       (D diagonal, S straight)

Low level (Figure 5.5): two subtasks in a local 150 m x 150 m frame. Diagonal: start (40, 40),
goal (140, 140), i.e. heading NE; straight (horizontal/vertical): start (40, 75), goal
(140, 75), heading E. Success: within 10 m of the local goal; failure: outside
``0 <= x, y <= 150``. Internal rewards +100 / -100 and the orientation shaping
``G = exp(-|theta - theta_hat|^2 / (30 * 30)) - 1`` (``theta_hat`` the bearing to the goal).

Our reading where the text is silent:

- The eight directions map onto the two subtasks by rotations of 0, 90, 180 or 270 degrees
  (``ROTATION``): each rotation turns direction ``k`` into its subtask's local direction. A
  rotation keeps the turning sense, so the local policy's turning rate is applied unchanged
  (no reflection, hence no inverse map for actions), and Equation 5.4 commutes with the map.
- The local frame is anchored where the subtask started: global position ``p`` maps to
  ``local_start + R (p - origin)``; headings are rotated by the same angle; turning rates are
  unchanged.
- ``G`` is evaluated on the state the step reached, added to every step's internal reward, and
  ``theta - theta_hat`` is wrapped to [-180, 180). Success is tested before failure (the goal
  circle touches the box edge at one point) and only at the end of each control step.
- Local success, failure and rewards only read the local state; the subtask ends when either
  holds (or when the global episode ends).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict
from torch import nn

from envs.ship import MAX_TURN, SIZE, ShipSteeringEnv, wrap_degrees
from hrl_torch.executor import LEVEL, PRIMITIVE, ExecutorConfig
from hrl_torch.experiment import AlgoSpec, DomainSpec
from hrl_torch.exploration import EpsilonGreedy, Greedy
from hrl_torch.graph import Primitive, Subtask, TaskGraph
from hrl_torch.hybrid import EpisodeBins, HybridLearner, TriggeredEpsilon
from hrl_torch.learners.pg import ActorCriticLearner, HPGRLLearner, PGConfig
from hrl_torch.learners.q_lambda import QLambdaLearner
from hrl_torch.tiles import TileCoder
from hrl_torch.trainer import TrainConfig

N_DIRECTIONS = 8
DIAGONAL, STRAIGHT = 0, 1
SUBTASK_NAMES = ("Diagonal", "HorizontalVertical")
DIRECTION_NAMES = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")
#: low-level subtask of each direction
SUBTASK_OF_DIRECTION = torch.tensor([STRAIGHT, DIAGONAL] * 4)
#: local start and goal of each subtask (Figure 5.5)
LOCAL_START = torch.tensor([[40.0, 40.0], [40.0, 75.0]])
LOCAL_GOAL = torch.tensor([[140.0, 140.0], [140.0, 75.0]])
LOCAL_SIZE = 150.0
GOAL_RADIUS = 10.0
SHAPING_WIDTH = 30.0  # degrees
SUCCESS_REWARD, FAILURE_REWARD = 100.0, -100.0
GATE_REWARD = 100.0  # the root's bonus for passing the gate
GRID_CELLS = 20  # per axis: 400 high-level states
#: rotation (compass degrees, clockwise) from direction k's frame to its subtask's frame
ROTATION = torch.tensor([90, 0, 0, -90, -90, 180, 180, 90])
_COS = torch.tensor([0, 1, 1, 0, 0, -1, -1, 0], dtype=torch.float32)
_SIN = torch.tensor([1, 0, 0, -1, -1, 0, 0, 1], dtype=torch.float32)


def _rotate(vec: torch.Tensor, cos: torch.Tensor, sin: torch.Tensor) -> torch.Tensor:
    """Turn compass vectors ``[B, 2]`` clockwise by the angle of ``(cos, sin)`` ``[B]``."""
    x, y = vec.unbind(-1)
    return torch.stack([x * cos + y * sin, y * cos - x * sin], dim=-1)


def to_local(state: torch.Tensor, origin: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
    """Global ship states into the local frame of direction ``k``'s subtask.

    Args:
        state: global ``[B, 4]`` = (x, y, theta, theta_dot).
        origin: global (x, y) ``[B, 2]`` where the subtask started.
        direction: ``[B]`` long in ``[0, 8)``.

    Returns:
        Local ``[B, 4]``: position ``local_start + R (p - origin)``, heading rotated by
        ``ROTATION[k]`` (wrapped), turning rate unchanged.
    """
    device = state.device
    cos, sin = _COS.to(device)[direction], _SIN.to(device)[direction]
    start = LOCAL_START.to(device)[SUBTASK_OF_DIRECTION.to(device)[direction]]
    position = start + _rotate(state[:, :2] - origin, cos, sin)
    theta = wrap_degrees(state[:, 2] + ROTATION.to(device)[direction])
    return torch.cat([position, theta[:, None], state[:, 3:]], dim=-1)


def to_global(local: torch.Tensor, origin: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
    """Inverse of ``to_local``: local ``[B, 4]`` back to global ``[B, 4]``."""
    device = local.device
    cos, sin = _COS.to(device)[direction], _SIN.to(device)[direction]
    start = LOCAL_START.to(device)[SUBTASK_OF_DIRECTION.to(device)[direction]]
    position = origin + _rotate(local[:, :2] - start, cos, -sin)
    theta = wrap_degrees(local[:, 2] - ROTATION.to(device)[direction])
    return torch.cat([position, theta[:, None], local[:, 3:]], dim=-1)


def bearing(source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Compass bearing in degrees ``[B]`` from positions ``source [B, 2]`` to ``target [B, 2]``."""
    d = target - source
    return torch.rad2deg(torch.atan2(d[:, 0], d[:, 1]))


def local_success(local: torch.Tensor, subtask: torch.Tensor) -> torch.Tensor:
    """``[B]``: within ``GOAL_RADIUS`` of the local goal."""
    goal = LOCAL_GOAL.to(local.device)[subtask]
    return (local[:, :2] - goal).norm(dim=-1) <= GOAL_RADIUS


def local_failure(local: torch.Tensor) -> torch.Tensor:
    """``[B]``: outside ``0 <= x, y <= 150``."""
    position = local[:, :2]
    return ((position < 0) | (position > LOCAL_SIZE)).any(-1)


def orientation_shaping(local: torch.Tensor, subtask: torch.Tensor) -> torch.Tensor:
    """``G = exp(-|theta - theta_hat|^2 / 30^2) - 1`` ``[B]``, in (-1, 0]."""
    goal = LOCAL_GOAL.to(local.device)[subtask]
    error = wrap_degrees(local[:, 2] - bearing(local[:, :2], goal))
    return torch.exp(-(error**2) / SHAPING_WIDTH**2) - 1.0


def internal_reward(local: torch.Tensor, subtask: torch.Tensor) -> torch.Tensor:
    """Internal reward ``[B]`` of a step that reached ``local``: ``G`` + 100 success - 100 failure.

    The env's -1 per step is external (it propagates to the root) and is not included.
    """
    success = local_success(local, subtask)
    failure = local_failure(local) & ~success
    terminal = torch.where(success, SUCCESS_REWARD, 0.0) + torch.where(failure, FAILURE_REWARD, 0.0)
    return orientation_shaping(local, subtask) + terminal


def grid_state(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """High-level state ``row * 20 + col`` ``[B]`` of 50 m cells (row from y, col from x).

    Positions outside [0, 1000] (a failed episode's last observation) clamp to edge cells.
    """
    cell = SIZE / GRID_CELLS
    col = torch.floor(x / cell).long().clamp(0, GRID_CELLS - 1)
    row = torch.floor(y / cell).long().clamp(0, GRID_CELLS - 1)
    return row * GRID_CELLS + col


def low_level_tile_coder() -> TileCoder:
    """The low-level subtasks' CMAC: 9 tilings of 5 x 5 x 36 x 5 over the local state."""
    return TileCoder(
        low=[0.0, 0.0, -180.0, -MAX_TURN],
        high=[LOCAL_SIZE, LOCAL_SIZE, 180.0, MAX_TURN],
        resolution=[5, 5, 36, 5],
        n_tilings=9,
        wrap=[False, False, True, False],
    )


def flat_tile_coder() -> TileCoder:
    """The flat PGRL policy's CMAC: 9 tilings of 20 x 20 x 36 x 5 over the global state."""
    return TileCoder(
        low=[0.0, 0.0, -180.0, -MAX_TURN],
        high=[SIZE, SIZE, 180.0, MAX_TURN],
        resolution=[20, 20, 36, 5],
        n_tilings=9,
        wrap=[False, False, True, False],
    )


# ---------------------------------------------------------------------- Figure 5.6 hierarchy
#: the eight direction subtasks under the root, in direction order (``GoN`` ... ``GoNW``)
DIRECTION_NODES = tuple(f"Go{d}" for d in DIRECTION_NAMES)
#: primitive steps one low-level invocation may take before the executor aborts it (our guard)
LOW_LEVEL_GUARD = 250


def low_level_reward(subtask: int):
    """Internal reward of a low-level subtask from its local state at ``s'`` (``[R, 4]``)."""

    def reward(local: torch.Tensor) -> torch.Tensor:
        kind = torch.full((local.shape[0],), subtask, dtype=torch.long, device=local.device)
        return internal_reward(local, kind)

    reward.__name__ = f"{SUBTASK_NAMES[subtask]}_internal_reward"
    return reward


#: one function per low-level subtask, shared by the directions that map onto it
LOW_LEVEL_REWARDS = (low_level_reward(DIAGONAL), low_level_reward(STRAIGHT))


class DirectionSubtask(Subtask):
    """Steer toward direction ``k`` in the local frame of its low-level subtask (Figure 5.5).

    Remembers where it started (the frame's origin); its features are the local state
    ``(x, y, theta, theta_dot)`` (``to_local``, with the rotation of ``k`` as constants); it
    ends on local success or failure.
    """

    def __init__(self, k: int) -> None:
        super().__init__(DIRECTION_NODES[k], ["Turn"], n_features=4, memory_size=2)
        self.direction = k
        self.subtask = int(SUBTASK_OF_DIRECTION[k])
        self._cos, self._sin = float(_COS[k]), float(_SIN[k])
        self._turn = float(ROTATION[k])
        self._start = [float(v) for v in LOCAL_START[self.subtask]]

    def remember(self, obs: TensorDict) -> torch.Tensor:
        return torch.stack([obs["x"], obs["y"]], dim=-1)

    def _position(self, obs: TensorDict, memory: torch.Tensor) -> torch.Tensor:
        dx, dy = obs["x"] - memory[:, 0], obs["y"] - memory[:, 1]
        c, s = self._cos, self._sin
        return torch.stack([dx * c + dy * s + self._start[0], dy * c - dx * s + self._start[1]], -1)

    def features(self, obs: TensorDict, memory: torch.Tensor) -> torch.Tensor:
        position = self._position(obs, memory)
        theta = wrap_degrees(obs["theta"] + self._turn)
        return torch.cat([position, theta[:, None], obs["theta_dot"][:, None]], dim=-1)

    def terminated(self, obs: TensorDict, memory: torch.Tensor) -> torch.Tensor:
        position = self._position(obs, memory)
        kind = torch.full_like(obs["x"], self.subtask, dtype=torch.long)
        return local_success(position, kind) | local_failure(position)


def _root_reward(out_of_bounds_reward: float):
    def pseudo(obs: TensorDict) -> torch.Tensor:
        position = torch.stack([obs["x"], obs["y"]], dim=-1)
        gone = ((position < 0) | (position > SIZE)).any(-1) & ~obs["success"]
        return GATE_REWARD * obs["success"].float() + out_of_bounds_reward * gone.float()

    return pseudo


def ship_hierarchy(out_of_bounds_reward: float = 0.0) -> TaskGraph:
    """Figure 5.6: Root (400 grid cells, 8 directions) -> direction subtasks -> Turn.

    The root's reward is the env's -1 per step plus ``GATE_REWARD`` when the ship passes the
    gate (and ``out_of_bounds_reward`` when it leaves the square; the text gives none).
    """
    root = Subtask(
        "Root",
        DIRECTION_NODES,
        n_states=GRID_CELLS * GRID_CELLS,
        abstract=lambda o: grid_state(o["x"], o["y"]),
        pseudo_reward=_root_reward(out_of_bounds_reward),
    )
    directions = [DirectionSubtask(k) for k in range(N_DIRECTIONS)]
    return TaskGraph("Root", [root, *directions, Primitive("Turn", action_dim=1)])


def flat_graph(out_of_bounds_reward: float = 0.0) -> TaskGraph:
    """One root choosing the turning rate from the global state (flat PGRL, actor-critic)."""
    root = Subtask(
        "Root",
        ["Turn"],
        features=lambda o: o["observation"],
        n_features=4,
        pseudo_reward=_root_reward(out_of_bounds_reward),
    )
    return TaskGraph("Root", [root, Primitive("Turn", action_dim=1)])


def direction_groups() -> dict[str, str]:
    """PG node -> parameter group: the directions share their low-level subtask's policy."""
    return {DIRECTION_NODES[k]: SUBTASK_NAMES[int(SUBTASK_OF_DIRECTION[k])] for k in range(8)}


def low_level_feature_rewards() -> dict[str, object]:
    """PG node -> internal reward from its local state (G + 100 success - 100 failure)."""
    return {DIRECTION_NODES[k]: LOW_LEVEL_REWARDS[int(SUBTASK_OF_DIRECTION[k])] for k in range(8)}


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
    """

    def __init__(
        self, graph: TaskGraph, n_learners: int, n_bins: int = 100, trigger_rate: float = 0.8
    ) -> None:
        super().__init__()
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
            self._rows = {"steps": torch.zeros(b), "calls": torch.zeros(b)}
        rows = self._rows
        rows["steps"] += prim["valid"].float()
        root = level["valid"][:, 0]
        ended = root & (level["terminal"][:, 0] | level["truncated"][:, 0])
        if self.hierarchical:
            rows["calls"] += root.float()
            executed = root & level["child_done"][:, 0]
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
        rows["steps"] = torch.where(ended, 0.0, rows["steps"])
        rows["calls"] = torch.where(ended, 0.0, rows["calls"])
        return ended.view(p, -1).sum(1), self._trigger()

    def _trigger(self) -> torch.Tensor:
        fired = torch.ones(self.episodes.events.shape[0], dtype=torch.bool)
        for bins in self.low:
            done = bins.completed()
            rate = bins.block_means()["success"]
            last = rate.gather(1, (done - 1).clamp_min(0)[:, None]).squeeze(1)
            fired &= (done > 0) & (last >= self.trigger_rate)
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
        alpha=params.flat_alpha, sigma=params.sigma, online=params.online, trace_len=1000
    )
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
    learner = ShipActorCritic(
        graph,
        n_learners,
        flat_tile_coder(),
        critic_tile_coder(),
        PGConfig(alpha=params.actor_alpha, sigma=params.sigma),
        params.critic_alpha,
    )
    learner.monitor = ShipMonitor(graph, n_learners)
    return learner


def make_env(seeds, envs_per_learner: int, backend: str = "torch") -> ShipSteeringEnv:
    """Ship steering for ``seeds`` (0.6 s control interval, 1000-step limit)."""
    if backend != "torch":
        raise ValueError(f"unknown backend {backend!r}")
    return ShipSteeringEnv(seeds, envs_per_learner)


#: about 50,000 episodes per learner at the hybrid's ~340 steps per episode
_TRAIN = TrainConfig(
    steps=17_000_000,
    eval_every=2_000_000,
    eval_episodes=100,
    eval_max_steps=1000,
    log_every=100_000,
    success_key="success",
)
_GUARDED = ExecutorConfig(max_subtask_steps=LOW_LEVEL_GUARD, on_timeout="abort")

DOMAIN = DomainSpec(
    name="ship-steering",
    description="ship steering through a gate (Miller et al. 1990; Section 5.3)",
    make_env=make_env,
    algos={
        "hybrid": AlgoSpec(
            make_graph=lambda: ship_hierarchy(PARAMS.out_of_bounds_reward),
            make_learner=make_hybrid,
            make_exploration=lambda config: EpsilonGreedy(PARAMS.epsilon),
            train=_TRAIN,
            envs_per_learner=1024,
            executor=_GUARDED,
            description="hierarchical hybrid: Q(lambda) root over 8 directions, HPGRL below",
        ),
        "flat-pg": AlgoSpec(
            make_graph=lambda: flat_graph(PARAMS.out_of_bounds_reward),
            make_learner=make_flat_pg,
            make_exploration=lambda config: Greedy(),  # unused: PG nodes sample
            train=_TRAIN,
            envs_per_learner=512,
            description="flat PGRL: Gaussian over 9 tilings of 20 x 20 x 36 x 5",
        ),
        "actor-critic": AlgoSpec(
            make_graph=lambda: flat_graph(PARAMS.out_of_bounds_reward),
            make_learner=make_actor_critic,
            make_exploration=lambda config: Greedy(),  # unused: PG nodes sample
            train=_TRAIN,
            envs_per_learner=512,
            description="actor-critic (Konda): flat PGRL actor, 5-D tile-coded Q critic",
        ),
    },
)
