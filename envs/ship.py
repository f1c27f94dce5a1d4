"""Ship steering (Miller et al., 1990; dissertation Section 5.3) as a torch-batched env.

## Description
A ship moves at constant speed ``V = 3`` m/s in a 1000 m x 1000 m square and must pass through
a gate between (350, 400) and (450, 400). Its dynamics (Equation 5.4, sampling interval
``Delta = 0.2`` s, time constant ``T = 5`` s, angles in degrees)::

    x[t+1]         = x[t] + Delta * V * sin(theta[t])
    y[t+1]         = y[t] + Delta * V * cos(theta[t])
    theta[t+1]     = theta[t] + Delta * theta_dot[t]
    theta_dot[t+1] = theta_dot[t] + Delta * (r[t] - theta_dot[t]) / T

``theta`` is a compass heading (0 = +y "north", 90 = +x "east"), wrapped to [-180, 180);
``theta_dot`` stays in [-15, 15] (clamped against rounding).

## Action Space
``Box(-15, 15, (1,))``: the desired turning rate ``r`` in deg/s (Table 5.1). An action outside
the range or not finite is a ``ValueError``. One env step holds ``r`` for ``action_repeat``
sampling intervals (default 3: the 0.6 s control interval of Section 5.3).

## Observation
``observation`` ``[4]`` = (x, y, theta, theta_dot), declared ``Box`` from (-1, -1, -180, -15)
to (1001, 1001, 180, 15): the box plus 1 m, because a failed episode's last observation lies
up to ``Delta * V = 0.6`` m outside. The TensorDict also carries the fields ``x``, ``y``,
``theta``, ``theta_dot`` ``[B]`` and ``success`` ``[B]`` (the ship passed the gate this step).

## Rewards
-1 per env step (the text's -1 per step; the gate bonus of the hierarchy is the agent's).

## Starting State
Uniform: x, y in [0, 1000], theta in [-180, 180), theta_dot in [-15, 15] ("a randomly chosen
position, orientation, and turning rate"). ``fixed_start`` or ``reset_to`` start rows from
given configurations instead (e.g. the two of Figure 5.12, ``FIGURE_5_12_STARTS``).

## Episode End
Terminated with success when the path of a sampling interval crosses the gate segment, and with
failure when the ship leaves [0, 1000]^2 (x < 0 or x > 1000 or y < 0 or y > 1000); a row that
terminates mid-step stops there (``duration`` is the time actually sailed). Crossing: the
interval goes from ``y < 400`` to ``y >= 400`` or back, at an x in [350, 450] (endpoints
included); the half-open side test counts a path that touches the line once, never twice.
Truncated after ``max_episode_steps`` env steps: the text gives no limit; we use 1000 (600 s
at ``action_repeat=3``, 1.8 km of sailing, more than any straight route to the gate).

## Version History
* v0: Equation 5.4 and Table 5.1 of the dissertation; start distribution and time limit ours.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from tensordict import TensorDict

from hrl_torch.env.batched import BatchedEnv

SIZE = 1000.0
MAX_TURN = 15.0  # deg/s, bound of theta_dot and of the action r
MAX_EPISODE_STEPS = 1000
FIGURE_5_12_STARTS = torch.tensor([[700.0, 700.0, 100.0, 3.65], [750.0, 180.0, 80.0, 7.9]])


@dataclass(frozen=True)
class ShipParams:
    """Constants of Equation 5.4 and the gate.

    Attributes:
        speed: ``V`` in m/s.
        time_constant: ``T`` in s.
        dt: sampling interval ``Delta`` in s.
        gate_y: the gate's y (it is horizontal).
        gate_x: the gate's ends in x.
    """

    speed: float = 3.0
    time_constant: float = 5.0
    dt: float = 0.2
    gate_y: float = 400.0
    gate_x: tuple[float, float] = (350.0, 450.0)


def wrap_degrees(angle: torch.Tensor) -> torch.Tensor:
    """Angles into [-180, 180).

    ``remainder(angle + 180, 360)`` lies in [0, 360]: it rounds to 360 when ``angle + 180`` is a
    tiny negative number. The second ``remainder`` maps that 360 to 0 and leaves [0, 360) as it
    is (no comparison and no ``where``: both are slow per element on CPU).
    """
    return torch.remainder(torch.remainder(angle + 180.0, 360.0), 360.0) - 180.0


def ship_dynamics(
    state: torch.Tensor, rate: torch.Tensor, params: ShipParams = ShipParams()
) -> torch.Tensor:
    """One sampling interval of Equation 5.4.

    Args:
        state: ``[..., 4]`` = (x, y, theta, theta_dot), angles in degrees.
        rate: desired turning rate ``r`` ``[...]`` in deg/s.
        params: constants.

    Returns:
        The next state ``[..., 4]``, theta wrapped to [-180, 180), theta_dot clamped to
        [-15, 15].
    """
    x, y, theta, theta_dot = state.unbind(-1)
    heading = torch.deg2rad(theta)
    step = params.dt * params.speed
    return torch.stack(
        [
            x + step * torch.sin(heading),
            y + step * torch.cos(heading),
            wrap_degrees(theta + params.dt * theta_dot),
            (theta_dot + params.dt * (rate - theta_dot) / params.time_constant).clamp(
                -MAX_TURN, MAX_TURN
            ),
        ],
        dim=-1,
    )


def gate_crossed(
    start: torch.Tensor, end: torch.Tensor, params: ShipParams = ShipParams()
) -> torch.Tensor:
    """Whether the segments ``start -> end`` (``[..., 2]`` positions) cross the gate: ``[...]``.

    The segment must go from ``y < gate_y`` to ``y >= gate_y`` (or back) and meet the line at an
    x in ``[gate_x[0], gate_x[1]]``. A level segment (``dy = 0``) never changes side, so its
    ``x_at`` (inf or NaN) is never looked at.
    """
    (x0, y0), (x1, y1) = start.unbind(-1), end.unbind(-1)
    sides = (y0 < params.gate_y) != (y1 < params.gate_y)
    x_at = x0 + (params.gate_y - y0) / (y1 - y0) * (x1 - x0)
    return sides & (x_at.clamp(*params.gate_x) == x_at)  # NaN: False, as a comparison


def out_of_bounds(position: torch.Tensor) -> torch.Tensor:
    """``[...]``: the position ``[..., 2]`` is outside [0, 1000]^2."""
    return ((position < 0) | (position > SIZE)).any(-1)


class ShipSteeringEnv(BatchedEnv):
    """Torch-batched ship steering (see the module docstring).

    Args:
        seeds: one seed per learner.
        envs_per_learner: envs per learner ``E``.
        action_repeat: sampling intervals per env step (3: 0.6 s control interval).
        max_episode_steps: time limit in env steps (``None``: none).
        fixed_start: ``[4]`` or ``[B, 4]`` configuration(s) every reset uses instead of the
            random start.
        params: constants of Equation 5.4.
        device: where the state lives.
    """

    state_keys = ("state", "success")
    observation_bounds = {
        "observation": ([-1.0, -1.0, -180.0, -MAX_TURN], [SIZE + 1, SIZE + 1, 180.0, MAX_TURN]),
    }
    action_bounds = ([-MAX_TURN], [MAX_TURN])

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        action_repeat: int = 3,
        max_episode_steps: int | None = MAX_EPISODE_STEPS,
        fixed_start: torch.Tensor | None = None,
        params: ShipParams = ShipParams(),
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__(seeds, envs_per_learner, None, max_episode_steps, device)
        if action_repeat < 1:
            raise ValueError(f"action_repeat must be >= 1, got {action_repeat}")
        self.action_repeat = action_repeat
        self.params = params
        self.fixed_start = None if fixed_start is None else self._as_rows(fixed_start)
        self.state = torch.zeros(self.batch_size, 4, device=self.device)
        self._low = torch.tensor([0.0, 0.0, -180.0, -MAX_TURN], device=self.device)
        self._span = torch.tensor([SIZE, SIZE, 180.0, MAX_TURN], device=self.device) - self._low
        self.success = torch.zeros(self.batch_size, dtype=torch.bool, device=self.device)

    def _as_rows(self, configs: torch.Tensor) -> torch.Tensor:
        configs = torch.as_tensor(configs, dtype=torch.float32, device=self.device)
        return configs.expand(self.batch_size, 4).clone()

    def reset_to(self, configs: torch.Tensor) -> TensorDict:
        """Reset every row to ``configs`` (``[4]`` or ``[B, 4]``); later resets are random."""
        out = self.reset()
        self.state = self._as_rows(configs)
        self.state[:, 2] = wrap_degrees(self.state[:, 2])
        fields = self._observe()
        for key, value in fields.items():
            out[key] = value
        return out

    def _reset_rows(self, mask: torch.Tensor) -> None:
        u = self.rng.uniform(4)  # drawn for every row so the stream never depends on data
        fresh = self._low + self._span * u
        if self.fixed_start is not None:
            fresh = self.fixed_start
        self.state = torch.where(mask[:, None], fresh, self.state)
        self.success = self.success & ~mask

    def _check_action(self, action: torch.Tensor) -> torch.Tensor:
        """The turning rates ``[B]``; a bad one raises unless its row is being reset.

        A row being reset sails whatever it was sent (even NaN): the reset replaces its state,
        and ``BatchedEnv.step`` its reward, duration and termination.
        """
        action = action.float()
        if action.shape not in ((self.batch_size,), (self.batch_size, 1)):
            raise ValueError(
                f"action must have shape [{self.batch_size}, 1], got {tuple(action.shape)}"
            )
        rate = action.reshape(self.batch_size)
        ok = rate.abs() <= MAX_TURN  # NaN compares False
        if self.deferred_action is not None:  # (no read: raised at the trainer's next read)
            self.deferred_action.record(~ok & ~self.done, action=rate)
            return torch.where(ok | self.done, rate, 0.0)  # (a bad row's rate: ignored)
        if not bool((ok | self.done).all()):
            row = int((~ok & ~self.done).nonzero()[0])
            raise _bad_rate(row, float(rate[row]))
        return rate

    def defer_checks(self):
        """Check turning rates with no device read from now on (``training.deferred``)."""
        from hrl_torch.common.devices import DeferredCheck

        self.deferred_action = DeferredCheck(
            lambda row, saved: _bad_rate(row, float(saved["action"][row]))
        )
        return self.deferred_action

    def _sail(self, state: torch.Tensor, rate: torch.Tensor):
        """One sampling interval of every row: ``(next state, crossed the gate, stops)``."""
        nxt = ship_dynamics(state, rate, self.params)
        position = nxt[:, :2]
        crossed = gate_crossed(state[:, :2], position, self.params)
        return nxt, crossed, crossed | out_of_bounds(position)

    def _step_all(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``action_repeat`` sampling intervals; a row stops where it crosses the gate or leaves.

        Every row sails the first interval; ``active`` rows sail the next ones, and
        ``intervals`` counts the intervals each row sailed.
        """
        rate = self._check_action(action)
        state, success, stop = self._sail(self.state, rate)
        active = ~stop
        intervals = torch.ones(self.batch_size, device=self.device)
        for _ in range(self.action_repeat - 1):
            nxt, crossed, stop = self._sail(state, rate)
            state = torch.where(active[:, None], nxt, state)
            intervals += active
            success |= crossed & active
            active &= ~stop
        self.state, self.success = state, success
        reward = torch.full((self.batch_size,), -1.0, device=self.device)
        return reward, intervals * self.params.dt, ~active

    def _observe(self) -> dict[str, torch.Tensor]:
        state = self.state.clone()
        x, y, theta, theta_dot = state.unbind(-1)
        return {
            "observation": state,
            "x": x,
            "y": y,
            "theta": theta,
            "theta_dot": theta_dot,
            "success": self.success.clone(),
        }


def gymnasium_env(render_mode: str | None = None):
    """``gymnasium.make("hrl/ShipSteering-v0")``: one row of ``ShipSteeringEnv``."""
    from hrl_torch.env.adapters import BatchedToGymnasium

    return BatchedToGymnasium(lambda seeds, n: ShipSteeringEnv(seeds, n), render_mode=render_mode)


def _bad_rate(row: int, rate: float) -> ValueError:
    """The error of a turning rate outside the ship's range in env row ``row``."""
    return ValueError(
        f"turning rate {rate} outside [-{MAX_TURN}, {MAX_TURN}] deg/s (env row {row})"
    )
