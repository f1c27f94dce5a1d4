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

import torch
from tensordict import TensorDict

from envs.ship import MAX_TURN, SIZE, out_of_bounds, wrap_degrees
from hrl_torch.common.devices import constant_on
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Primitive, Subtask
from hrl_torch.modules.tiles import TileCoder

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
#: the distinct rotations, and the one of each direction (its features' heading)
TURNS = torch.tensor([90.0, 0.0, -90.0, 180.0])
TURN_OF_DIRECTION = (0, 1, 1, 2, 2, 3, 3, 0)
_GRID_STRIDES = torch.tensor([1, GRID_CELLS])  # (col, row)


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
    cos, sin = constant_on(_COS, device)[direction], constant_on(_SIN, device)[direction]
    start = constant_on(LOCAL_START, device)[constant_on(SUBTASK_OF_DIRECTION, device)[direction]]
    position = start + _rotate(state[:, :2] - origin, cos, sin)
    theta = wrap_degrees(state[:, 2] + constant_on(ROTATION, device)[direction])
    return torch.cat([position, theta[:, None], state[:, 3:]], dim=-1)


def to_global(local: torch.Tensor, origin: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
    """Inverse of ``to_local``: local ``[B, 4]`` back to global ``[B, 4]``."""
    device = local.device
    cos, sin = constant_on(_COS, device)[direction], constant_on(_SIN, device)[direction]
    start = constant_on(LOCAL_START, device)[constant_on(SUBTASK_OF_DIRECTION, device)[direction]]
    position = origin + _rotate(local[:, :2] - start, cos, -sin)
    theta = wrap_degrees(local[:, 2] - constant_on(ROTATION, device)[direction])
    return torch.cat([position, theta[:, None], local[:, 3:]], dim=-1)


def bearing(source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Compass bearing in degrees ``[B]`` from positions ``source [B, 2]`` to ``target [B, 2]``."""
    d = target - source
    return torch.rad2deg(torch.atan2(d[:, 0], d[:, 1]))


def _at_goal(position: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
    """``[B]``: ``position [B, 2]`` within ``GOAL_RADIUS`` of ``goal`` (``[2]`` or ``[B, 2]``)."""
    return (position - goal).norm(dim=-1) <= GOAL_RADIUS


def _outside(position: torch.Tensor) -> torch.Tensor:
    """``[B]``: ``position [B, 2]`` is outside ``0 <= x, y <= 150``."""
    return ((position < 0) | (position > LOCAL_SIZE)).any(-1)


def _shaping(local: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
    """``G`` of local states ``[B, 4]`` toward ``goal`` (``[2]`` or ``[B, 2]``)."""
    error = wrap_degrees(local[:, 2] - bearing(local[:, :2], goal))
    return torch.exp(error * error / -(SHAPING_WIDTH**2)) - 1.0  # -(e^2) / w^2, exactly


def _internal_reward(local: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
    """``G`` + 100 success - 100 failure of local states ``[B, 4]`` toward ``goal``.

    Success is tested first; the terminal part is -100 * 0 = -0.0 on neither, which leaves
    ``G`` (never -0.0) unchanged.
    """
    position = local[:, :2]
    failure = FAILURE_REWARD * _outside(position)
    terminal = failure.masked_fill(_at_goal(position, goal), SUCCESS_REWARD)
    return _shaping(local, goal) + terminal


def local_success(local: torch.Tensor, subtask: torch.Tensor) -> torch.Tensor:
    """``[B]``: within ``GOAL_RADIUS`` of the local goal."""
    return _at_goal(local[:, :2], constant_on(LOCAL_GOAL, local.device)[subtask])


def local_failure(local: torch.Tensor) -> torch.Tensor:
    """``[B]``: outside ``0 <= x, y <= 150``."""
    return _outside(local[:, :2])


def orientation_shaping(local: torch.Tensor, subtask: torch.Tensor) -> torch.Tensor:
    """``G = exp(-|theta - theta_hat|^2 / 30^2) - 1`` ``[B]``, in (-1, 0]."""
    return _shaping(local, constant_on(LOCAL_GOAL, local.device)[subtask])


def internal_reward(local: torch.Tensor, subtask: torch.Tensor) -> torch.Tensor:
    """Internal reward ``[B]`` of a step that reached ``local``: ``G`` + 100 success - 100 failure.

    The env's -1 per step is external (it propagates to the root) and is not included.
    """
    return _internal_reward(local, constant_on(LOCAL_GOAL, local.device)[subtask])


def grid_cell(position: torch.Tensor) -> torch.Tensor:
    """``grid_state`` of positions ``[B, 2]`` = (x, y)."""
    cell = torch.floor(position / (SIZE / GRID_CELLS)).long().clamp(0, GRID_CELLS - 1)
    return (cell * constant_on(_GRID_STRIDES, cell.device)).sum(-1)


def grid_state(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """High-level state ``row * 20 + col`` ``[B]`` of 50 m cells (row from y, col from x).

    Positions outside [0, 1000] (a failed episode's last observation) clamp to edge cells.
    """
    return grid_cell(torch.stack([x, y], dim=-1))


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
    goal = LOCAL_GOAL[subtask].clone()

    def reward(local: torch.Tensor) -> torch.Tensor:
        return _internal_reward(local, constant_on(goal, local.device))

    reward.__name__ = f"{SUBTASK_NAMES[subtask]}_internal_reward"
    return reward


#: one function per low-level subtask, shared by the directions that map onto it
LOW_LEVEL_REWARDS = (low_level_reward(DIAGONAL), low_level_reward(STRAIGHT))


class _Memo:
    """The value last computed from some tensors, returned again while they are unchanged.

    Unchanged: the same tensor, or a view of the same memory (a subtask's memory is a new view
    at every call), at the same version (in-place writes bump it). The memo keeps the tensors,
    so their memory is not reused while it holds them.
    """

    def __init__(self) -> None:
        self._key: list[tuple[torch.Tensor, int]] = []
        self._value = None

    def __call__(self, tensors: tuple[torch.Tensor, ...], compute):
        if any(t.is_inference() for t in tensors):  # no version counter
            return compute()
        if len(tensors) != len(self._key) or not all(map(_unchanged, tensors, self._key)):
            self._value = compute()
            self._key = [(t, t._version) for t in tensors]
        return self._value


def _unchanged(t: torch.Tensor, key: tuple[torch.Tensor, int]) -> bool:
    ref, version = key
    same = t is ref or (
        t.data_ptr() == ref.data_ptr()
        and t.device == ref.device
        and t.dtype == ref.dtype
        and t.shape == ref.shape
        and t.stride() == ref.stride()
    )
    return same and t._version == version


class ShipFrames:
    """What the ship's predicates share within a step, each computed once per observation.

    The graph calls every direction's ``terminated`` and ``features`` (and the root's
    ``abstract`` and pseudo reward, every direction's ``remember``) on the same observation:
    they share the position ``(x, y)`` ``[B, 2]`` and the heading turned by each distinct
    rotation, ``wrap(theta + TURNS)`` ``[B, 4]`` (with ``theta_dot`` as a column ``[B, 1]``).
    """

    def __init__(self) -> None:
        self._position, self._headings = _Memo(), _Memo()

    def position(self, obs: TensorDict) -> torch.Tensor:
        """``(x, y)`` ``[B, 2]``."""
        x, y = obs["x"], obs["y"]
        return self._position((x, y), lambda: torch.stack([x, y], dim=-1))

    def headings(self, obs: TensorDict) -> tuple[tuple[torch.Tensor, ...], torch.Tensor]:
        """``(wrap(theta + TURNS[j]) [B, 1] for each j, theta_dot [B, 1])``."""
        theta, theta_dot = obs["theta"], obs["theta_dot"]

        def compute():
            turned = wrap_degrees(theta[:, None] + constant_on(TURNS, theta.device))
            return turned.split(1, dim=1), theta_dot[:, None]

        return self._headings((theta, theta_dot), compute)


class DirectionSubtask(Subtask):
    """Steer toward direction ``k`` in the local frame of its low-level subtask (Figure 5.5).

    Remembers where it started (the frame's origin); its features are the local state
    ``(x, y, theta, theta_dot)`` (``to_local``, with the rotation of ``k`` as constants); it
    ends on local success or failure.

    The rotation ``R`` of ``k`` has one entry +-1 per row, so ``R (p - origin)`` swaps and negates
    the components of ``p - origin``: the same numbers as ``to_local``'s products and sums (for
    finite positions), with fewer ops. The local position is computed once per observation and
    memory (``terminated`` and ``features`` share it), from ``frames`` (shared by the
    hierarchy's nodes).

    Args:
        k: the direction, ``0`` (N) to ``7`` (NW).
        frames: the hierarchy's shared per-observation values (default: this node's own).
    """

    def __init__(self, k: int, frames: ShipFrames | None = None) -> None:
        super().__init__(DIRECTION_NODES[k], ["Turn"], n_features=4, memory_size=2)
        self.direction = k
        self.subtask = int(SUBTASK_OF_DIRECTION[k])
        self.frames = frames if frames is not None else ShipFrames()
        cos, sin = float(_COS[k]), float(_SIN[k])
        self._swap = cos == 0  # R d = (s dy, -s dx) or (c dx, c dy)
        sign = [sin, -sin] if self._swap else [cos, cos]
        self.register_buffer("_sign", torch.tensor(sign), persistent=False)
        self.register_buffer("_start", LOCAL_START[self.subtask].clone(), persistent=False)
        self.register_buffer("_goal", LOCAL_GOAL[self.subtask].clone(), persistent=False)
        self._turn = TURN_OF_DIRECTION[k]
        self._local = _Memo()

    def remember(self, obs: TensorDict) -> torch.Tensor:
        return self.frames.position(obs)  # shared: read only (the graph copies it)

    def local_position(self, obs: TensorDict, memory: torch.Tensor) -> torch.Tensor:
        """``local_start + R (p - origin)`` ``[B, 2]``, computed once per input (read only)."""
        tensors = (obs["x"], obs["y"], memory)

        def compute():
            d = self.frames.position(obs) - memory
            return torch.addcmul(self._start, d.flip(-1) if self._swap else d, self._sign)

        return self._local(tensors, compute)

    def features(self, obs: TensorDict, memory: torch.Tensor) -> torch.Tensor:
        turned, theta_dot = self.frames.headings(obs)
        position = self.local_position(obs, memory)
        return torch.cat([position, turned[self._turn], theta_dot], dim=-1)

    def terminated(self, obs: TensorDict, memory: torch.Tensor) -> torch.Tensor:
        position = self.local_position(obs, memory)
        return _at_goal(position, self._goal) | _outside(position)


def _root_reward(out_of_bounds_reward: float, frames: ShipFrames):
    def pseudo(obs: TensorDict) -> torch.Tensor:
        success = obs["success"]
        gone = out_of_bounds(frames.position(obs)) & ~success
        return GATE_REWARD * success + out_of_bounds_reward * gone  # bool * float: 1.0 or 0.0

    return pseudo


def ship_hierarchy(out_of_bounds_reward: float = 0.0) -> TaskGraph:
    """Figure 5.6: Root (400 grid cells, 8 directions) -> direction subtasks -> Turn.

    The root's reward is the env's -1 per step plus ``GATE_REWARD`` when the ship passes the
    gate (and ``out_of_bounds_reward`` when it leaves the square; the text gives none).
    """
    frames = ShipFrames()
    root = Subtask(
        "Root",
        DIRECTION_NODES,
        n_states=GRID_CELLS * GRID_CELLS,
        abstract=lambda o: grid_cell(frames.position(o)),
        pseudo_reward=_root_reward(out_of_bounds_reward, frames),
    )
    directions = [DirectionSubtask(k, frames) for k in range(N_DIRECTIONS)]
    return TaskGraph("Root", [root, *directions, Primitive("Turn", action_dim=1)])


def flat_graph(out_of_bounds_reward: float = 0.0) -> TaskGraph:
    """One root choosing the turning rate from the global state (flat PGRL, actor-critic)."""
    root = Subtask(
        "Root",
        ["Turn"],
        features=lambda o: o["observation"],
        n_features=4,
        pseudo_reward=_root_reward(out_of_bounds_reward, ShipFrames()),
    )
    return TaskGraph("Root", [root, Primitive("Turn", action_dim=1)])


def direction_groups() -> dict[str, str]:
    """PG node -> parameter group: the directions share their low-level subtask's policy."""
    return {DIRECTION_NODES[k]: SUBTASK_NAMES[int(SUBTASK_OF_DIRECTION[k])] for k in range(8)}


def low_level_feature_rewards() -> dict[str, object]:
    """PG node -> internal reward from its local state (G + 100 success - 100 failure)."""
    return {DIRECTION_NODES[k]: LOW_LEVEL_REWARDS[int(SUBTASK_OF_DIRECTION[k])] for k in range(8)}
