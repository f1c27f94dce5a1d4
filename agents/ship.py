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

from envs.ship import MAX_TURN, SIZE, wrap_degrees
from hrl_torch.tiles import TileCoder

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
