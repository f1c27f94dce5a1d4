"""The AGV scheduling task of Figure 4.4 (Section 4.3.2), batched, discrete or continuous time.

## Description
One AGV moves raw parts from a warehouse to three workstations M1-M3 and brings the finished
assemblies back. Parts of type ``i`` arrive at the warehouse (mix 40/35/25 %) and wait in bay
``Wi``; the AGV loads one, drops it at ``Di`` (the input buffer of ``Mi``), ``Mi`` assembles its
parts one at a time into ``Pi`` (its output buffer), and the AGV loads assemblies at ``Pi`` and
unloads them at ``WA`` (warehouse, assemblies in). Travel is one-way along the arrows; 33
locations; ``Turn`` takes the branch at the junctions ``J1``-``J3`` (into a workstation) and
``JW`` (into the warehouse lane), ``Forward`` follows the lane the AGV is on::

      WX --> TL -->  1 --> J1 -->  3 --> J2 -->  5 --> J3 --> TR
      ^      ^             v             v             v      v
      W3     21            D1            D2            D3      8
      ^      ^             | [M1]        | [M2]        | [M3] v
      W2     20            |             |             |       9
      ^      ^             v             v             v      v
      W1     19            P1            P2            P3     10
      ^      ^             v             v             v      v
      WA <-- JW <-- 17 <-- K1 <-- 15 <-- K2 <-- 13 <-- K3 <-- BR

Location indices: TL 0, 1, J1 2, 3, J2 4, 5, J3 6, TR 7, 8, 9, 10, BR 11, K3 12, 13, K2 14, 15,
K1 16, 17, JW 18, 19, 20, 21 (the main loop, clockwise), D1 22, P1 23, D2 24, P2 25, D3 26,
P3 27, WA 28, W1 29, W2 30, W3 31, WX 32. The column ``JW-19-20-21`` bypasses the warehouse.

## Action Space
``Discrete(5)``: 0 ``Forward``, 1 ``Turn`` (away from a junction it does not move), 2 ``Load``
(AGV empty: part ``i`` at ``Wi`` if the bay holds one, assembly ``i`` at ``Pi`` if the buffer
holds one), 3 ``Unload`` (part ``i`` at ``Di`` if it has room; any assembly at ``WA``; part
``i`` back into bay ``Wi``, which then holds one part: a surplus part is lost, so no state is
a dead end), 4 ``Idle`` (wait). An action that cannot apply only takes time. The AGV carries
one item at a time.

## Observation
A TensorDict: ``observation``, the flat state index in ``[0, 1_347_192)``
(``33 x 3**6 x 7 x 2**3``; mixed radix ``location, status, drop_off_1..3, pick_up_1..3,
warehouse_1..3``, most significant first), its decoded fields ``location`` (33), ``status``
(0 empty, ``i`` carrying part ``i``, ``3 + i`` carrying assembly ``i``), ``drop_off_i`` and
``pick_up_i`` (0-2 items in ``Di`` / ``Pi``; the part on the machine counts in ``Di``),
``warehouse_i`` (0/1), plus ``delivery`` (what the step delivered: 0 nothing, ``i`` part
``i`` into ``Di``, ``3 + i`` assembly ``i`` into the warehouse; it drives the subtasks'
termination) and the float counts ``assemblies_delivered`` and ``parts_lost`` of the step.
Throughput (Figures 4.6/4.7) is the sum of ``assemblies_delivered`` over a window divided by
the window's time (the sum of ``duration``).

## Dynamics
An action's effect happens at its decision epoch; arrivals and assembly then run for its
duration ``tau``. An arrival of a type whose bay is full is lost (``parts_lost``): the
warehouse state stays binary. ``Mi`` starts a part when ``Di`` holds one and ``Pi`` has room
(blocking), and moves it to ``Pi`` after its assembly time; the arrival and assembly timers
are hidden state. Every step draws the same random numbers whatever the state (a learner's
stream does not depend on its population). Distributions (``AGVTiming``; "variance" in
Tables 4.1/4.2 is read as the variance, so std = sqrt(variance)):

* discrete time (Table 4.1): ``tau = 1``; inter-arrival uniform on ``{10..14}`` (mean 12,
  variance 2); assembly ``mean - 4 + Binomial(8, 1/2)`` steps (means 6/10/12, variance 2: a
  Poisson cannot have variance 2 and these means).
* continuous time (Table 4.2): ``tau ~ Normal(10, var 2)`` s; inter-arrival
  ``Uniform(100 -+ sqrt(60))`` s (variance 20); assembly ``Normal(100/120/180, var 20)`` s.
  Normals are truncated at 6 standard deviations.

## Rewards
``AGVRewards``: lump reward ``k`` (+1 per assembly delivered to the warehouse by default, an
optional amount per part dropped at its workstation) plus a reward rate times ``tau``
(default 0). With the defaults the gain is the throughput.

## Starting State
AGV empty at ``WA``; buffers and warehouse empty; machines idle; first arrival one
inter-arrival time away.

## Episode End
A continuing task: never terminated, no time limit by default.

## Version History
* v0: layout, dynamics and rewards above.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import torch

from envs import agv_common as common
from hrl_torch.common.ops import one_hot_mask
from hrl_torch.env.batched import BatchedEnv

# -- layout: (name, forward successor, turn successor or None); index = position in the list
# fmt: off
_NODES = (
    ("TL", 1, None), ("1", 2, None), ("J1", 3, 22), ("3", 4, None), ("J2", 5, 24),
    ("5", 6, None), ("J3", 7, 26), ("TR", 8, None), ("8", 9, None), ("9", 10, None),
    ("10", 11, None), ("BR", 12, None), ("K3", 13, None), ("13", 14, None), ("K2", 15, None),
    ("15", 16, None), ("K1", 17, None), ("17", 18, None), ("JW", 19, 28), ("19", 20, None),
    ("20", 21, None), ("21", 0, None),
    ("D1", 23, None), ("P1", 16, None), ("D2", 25, None), ("P2", 14, None), ("D3", 27, None),
    ("P3", 12, None),
    ("WA", 29, None), ("W1", 30, None), ("W2", 31, None), ("W3", 32, None), ("WX", 0, None),
)
# fmt: on
LOCATION_NAMES = tuple(n for n, _, _ in _NODES)
N_LOCATIONS = len(_NODES)
N_STATIONS = 3
CAPACITY = 2
LOC = {name: k for k, name in enumerate(LOCATION_NAMES)}
DROP_OFF = tuple(LOC[f"D{i}"] for i in range(1, 4))
PICK_UP = tuple(LOC[f"P{i}"] for i in range(1, 4))
BAYS = tuple(LOC[f"W{i}"] for i in range(1, 4))
WAREHOUSE_DROP = LOC["WA"]
START = LOC["WA"]
N_STATUS = 1 + 2 * N_STATIONS
EMPTY = 0
N_STATES = N_LOCATIONS * (CAPACITY + 1) ** (2 * N_STATIONS) * N_STATUS * 2**N_STATIONS
FORWARD, TURN, LOAD, UNLOAD, IDLE = range(5)
N_ACTIONS = 5
ACTION_NAMES = ("Forward", "Turn", "Load", "Unload", "Idle")


def successors() -> torch.Tensor:
    """``[33, 2]`` next location for ``Forward`` / ``Turn`` (a no-branch ``Turn`` stays put)."""
    return torch.tensor([[f, k if t is None else t] for k, (_, f, t) in enumerate(_NODES)])


def station_of(locations: Sequence[int]) -> torch.Tensor:
    """``[33]`` long: ``i`` at ``locations[i]``, -1 elsewhere."""
    return common.station_of(N_LOCATIONS, locations)


@lru_cache(maxsize=1)
def shortest_paths() -> tuple[torch.Tensor, torch.Tensor]:
    """``(distance, first_move)`` ``[33, 33]`` (``[from, to]``; ``envs.agv_common``)."""
    return common.shortest_paths(successors())


# -- flat state index
_RADICES = common.radices(N_LOCATIONS, N_STATIONS, CAPACITY)


def encode(location, status, drop_off, pick_up, warehouse) -> torch.Tensor:
    """Flat state index (mixed radix, most significant first).

    Args:
        location: ``[...]`` in ``[0, 33)``.
        status: ``[...]`` in ``[0, 7)``.
        drop_off: ``[..., 3]`` in ``[0, 3)``.
        pick_up: ``[..., 3]`` in ``[0, 3)``.
        warehouse: ``[..., 3]`` in ``{0, 1}``.
    """
    return common.encode(_RADICES, location, status, drop_off, pick_up, warehouse)


def decode(index: torch.Tensor) -> dict[str, torch.Tensor]:
    """Observation fields of flat state indices (any shape)."""
    return common.decode(_RADICES, index)


# -- model parameters
@dataclass(frozen=True)
class AGVTiming:
    """Time model: means and variances of Tables 4.1 (discrete) / 4.2 (continuous).

    Attributes:
        continuous: event-driven continuous time (else every action takes one step).
        action_mean: mean duration of a primitive action (continuous time).
        action_var: its variance.
        interarrival_mean: mean time between part arrivals (uniform distribution).
        interarrival_var: its variance.
        assembly_mean: mean assembly time per part type.
        assembly_var: variance of the assembly times.
        part_mix: probability of each part type in the arrival stream.
    """

    continuous: bool
    action_mean: float
    action_var: float
    interarrival_mean: float
    interarrival_var: float
    assembly_mean: tuple[float, ...]
    assembly_var: float
    part_mix: tuple[float, ...] = (0.40, 0.35, 0.25)


DISCRETE = AGVTiming(False, 1.0, 0.0, 12.0, 2.0, (6.0, 10.0, 12.0), 2.0)
CONTINUOUS = AGVTiming(True, 10.0, 2.0, 100.0, 20.0, (100.0, 120.0, 180.0), 20.0)
_TRUNCATE = 6.0  # normals are cut at mean -+ 6 std


@dataclass(frozen=True)
class AGVRewards:
    """Reward of a step: ``assembly * assemblies + part * parts + rate * tau``.

    Attributes:
        assembly: lump reward per assembly delivered to the warehouse.
        part: lump reward per raw part dropped at its workstation.
        rate: reward per unit of time.
    """

    assembly: float = 1.0
    part: float = 0.0
    rate: float = 0.0


class AGVEnv(BatchedEnv):
    """Torch-batched AGV scheduling task (see the module docstring).

    Args:
        seeds: one seed per learner.
        envs_per_learner: envs per learner ``E``; the batch is ``len(seeds) * E``.
        continuous: use ``CONTINUOUS`` timing (Table 4.2) instead of ``DISCRETE`` (Table 4.1).
        timing: explicit time model (overrides ``continuous``).
        rewards: reward definition.
        max_episode_steps: optional time limit (none: a continuing task).
        device: where the state lives.
    """

    state_keys = (
        "location",
        "status",
        "drop_off",
        "pick_up",
        "warehouse",
        "busy",
        "to_finish",
        "to_arrival",
        "delivery",
        "delivered",
        "lost",
    )

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        continuous: bool = False,
        timing: AGVTiming | None = None,
        rewards: AGVRewards | None = None,
        max_episode_steps: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__(seeds, envs_per_learner, N_ACTIONS, max_episode_steps, device)
        self.timing = timing or (CONTINUOUS if continuous else DISCRETE)
        self.rewards = rewards or AGVRewards()
        t, n, dev = self.timing, N_STATIONS, self.device
        if len(t.assembly_mean) != n or len(t.part_mix) != n:
            raise ValueError(f"timing needs {n} assembly means and part fractions")
        self.observation_sizes = {
            "observation": N_STATES,
            "location": N_LOCATIONS,
            "status": N_STATUS,
            **{f"{k}_{i + 1}": CAPACITY + 1 for k in ("drop_off", "pick_up") for i in range(n)},
            **{f"warehouse_{i + 1}": 2 for i in range(n)},
            "delivery": N_STATUS,
        }
        self.succ = successors().to(dev)
        self.drop_station = station_of(DROP_OFF).to(dev)
        self.pick_station = station_of(PICK_UP).to(dev)
        self.bay_type = station_of(BAYS).to(dev)
        self._mix_cdf = torch.tensor(t.part_mix, device=dev).cumsum(0)[:-1]
        self._asm_mean = torch.tensor(t.assembly_mean, device=dev)
        self._set_bounds()
        b = self.batch_size
        self.location = torch.full((b,), START, dtype=torch.long, device=dev)
        self.status = torch.zeros(b, dtype=torch.long, device=dev)
        self.drop_off = torch.zeros(b, n, dtype=torch.long, device=dev)
        self.pick_up = torch.zeros(b, n, dtype=torch.long, device=dev)
        self.warehouse = torch.zeros(b, n, dtype=torch.long, device=dev)
        self.busy = torch.zeros(b, n, dtype=torch.bool, device=dev)
        self.to_finish = torch.zeros(b, n, device=dev)
        self.to_arrival = torch.zeros(b, device=dev)
        self.delivery = torch.zeros(b, dtype=torch.long, device=dev)
        self.delivered = torch.zeros(b, device=dev)
        self.lost = torch.zeros(b, device=dev)

    # -- distributions (each draws for every row, whatever the state)
    def _set_bounds(self) -> None:
        """Support of every distribution, and how many events one step can hold."""
        t = self.timing
        if t.continuous:
            sd = math.sqrt(t.action_var)
            self._tau_bounds = (
                max(t.action_mean - _TRUNCATE * sd, 1e-3 * t.action_mean),
                t.action_mean + _TRUNCATE * sd,
            )
            half = math.sqrt(3.0 * t.interarrival_var)
            self._gap_bounds = (t.interarrival_mean - half, t.interarrival_mean + half)
            sd = math.sqrt(t.assembly_var)
            self._asm_low = [max(m - _TRUNCATE * sd, 1e-3 * m) for m in t.assembly_mean]
            self._asm_floor = torch.tensor(self._asm_low, device=self.device)
        else:
            self._tau_bounds = (1.0, 1.0)
            width = round(math.sqrt(12.0 * t.interarrival_var + 1.0))  # (n**2 - 1) / 12 = var
            low = round(t.interarrival_mean - (width - 1) / 2)
            self._gap_bounds = (float(low), float(low + width - 1))
            self._trials = round(4 * t.assembly_var)  # Binomial(n, 1/2): variance n / 4
            self._asm_low = [m - self._trials / 2 for m in t.assembly_mean]
        if self._gap_bounds[0] <= 0 or min(self._asm_low) <= 0:
            raise ValueError(f"inter-arrival and assembly times must stay positive: {t}")
        # events of one process in a step are >= min gap apart: at most 1 + floor(tau / gap)
        min_gap = min(self._gap_bounds[0], *self._asm_low)
        self._events_per_step = 1 + math.floor(self._tau_bounds[1] / min_gap)

    def _draw_tau(self) -> torch.Tensor:
        if not self.timing.continuous:
            return torch.ones(self.batch_size, device=self.device)
        t = self.timing
        z = self.rng.normal()
        return (t.action_mean + math.sqrt(t.action_var) * z).clamp(*self._tau_bounds)

    def _draw_gap(self) -> torch.Tensor:
        low, high = self._gap_bounds
        if self.timing.continuous:
            return low + (high - low) * self.rng.uniform()
        return low + self.rng.integers(int(high - low) + 1).float()

    def _draw_assembly(self) -> torch.Tensor:
        """Assembly times ``[B, 3]``."""
        t = self.timing
        if t.continuous:
            z = self.rng.normal(N_STATIONS).clamp(-_TRUNCATE, _TRUNCATE)
            return (self._asm_mean + math.sqrt(t.assembly_var) * z).clamp_min(self._asm_floor)
        coins = self.rng.uniform(N_STATIONS * self._trials).view(-1, N_STATIONS, self._trials)
        return self._asm_mean - self._trials / 2 + (coins < 0.5).sum(-1).float()

    def _draw_part_type(self) -> torch.Tensor:
        return (self.rng.uniform()[:, None] >= self._mix_cdf).sum(-1)

    # -- BatchedEnv hooks
    def _reset_rows(self, mask: torch.Tensor) -> None:
        gap = self._draw_gap()
        m2 = mask[:, None]
        self.location = torch.where(mask, START, self.location)
        for name in ("status", "delivery"):
            setattr(self, name, torch.where(mask, 0, getattr(self, name)))
        for name in ("drop_off", "pick_up", "warehouse", "to_finish"):
            setattr(self, name, torch.where(m2, 0, getattr(self, name)))
        self.busy = self.busy & ~m2
        self.delivered = torch.where(mask, 0.0, self.delivered)
        self.lost = torch.where(mask, 0.0, self.lost)
        self.to_arrival = torch.where(mask, gap, self.to_arrival)

    def _step_all(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        tau = self._draw_tau()
        parts_in, lost = self._act(action.long())
        self.lost = lost + self._advance(tau)
        r = self.rewards
        reward = r.assembly * self.delivered + r.part * parts_in + r.rate * tau
        return reward, tau, torch.zeros_like(self.delivered, dtype=torch.bool)

    def _observe(self) -> dict[str, torch.Tensor]:
        fields = decode(
            encode(self.location, self.status, self.drop_off, self.pick_up, self.warehouse)
        )
        fields.update(
            delivery=self.delivery.clone(),
            assemblies_delivered=self.delivered.clone(),
            parts_lost=self.lost.clone(),
        )
        return fields

    # -- dynamics
    def _act(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Apply the AGV's action at the decision epoch.

        Returns:
            ``(parts dropped at workstations, parts lost by returning them to a full bay)``,
            both ``[B]`` float.
        """
        loc, status, n = self.location, self.status, N_STATIONS
        part = status - 1  # part type carried (valid when 1 <= status <= n)
        carrying_part = (status >= 1) & (status <= n)
        bay, pick, drop = self.bay_type[loc], self.pick_station[loc], self.drop_station[loc]

        def count(buffer: torch.Tensor, station: torch.Tensor) -> torch.Tensor:
            return buffer.gather(1, station.clamp(0, n - 1)[:, None]).squeeze(1)

        def one_hot(station: torch.Tensor, when: torch.Tensor) -> torch.Tensor:
            hot = one_hot_mask(station.clamp(0, n - 1), n)
            return (hot & when[:, None]).long()

        load = (action == LOAD) & (status == EMPTY)
        load_part = load & (bay >= 0) & (count(self.warehouse, bay) > 0)
        load_asm = load & (pick >= 0) & (count(self.pick_up, pick) > 0)
        unload = action == UNLOAD
        room = count(self.drop_off, drop) < CAPACITY
        drop_part = unload & carrying_part & (drop == part) & room
        back_part = unload & carrying_part & (bay == part)
        deliver = unload & (status > n) & (loc == WAREHOUSE_DROP)
        lost = back_part & (count(self.warehouse, bay) > 0)

        warehouse = self.warehouse - one_hot(bay, load_part) + one_hot(bay, back_part)
        self.warehouse = warehouse.clamp_max(1)
        self.pick_up = self.pick_up - one_hot(pick, load_asm)
        self.drop_off = self.drop_off + one_hot(drop, drop_part)
        self.delivery = torch.where(drop_part | deliver, status, 0)
        self.delivered = deliver.float()
        status = torch.where(load_part, 1 + bay, status)
        status = torch.where(load_asm, 1 + n + pick, status)
        self.status = torch.where(drop_part | back_part | deliver, EMPTY, status)
        moved = self.succ[loc, action.clamp(0, 1)]
        self.location = torch.where(action <= TURN, moved, loc)
        return drop_part.float(), lost.float()

    def _advance(self, tau: torch.Tensor) -> torch.Tensor:
        """Run arrivals and assembly for ``tau``; return the arrivals lost to full bays."""
        n = N_STATIONS
        # machines that can start now (a part was dropped or an output slot freed)
        new = self._draw_assembly()
        start = ~self.busy & (self.drop_off > 0) & (self.pick_up < CAPACITY)
        self.to_finish = torch.where(start, new, self.to_finish)
        self.busy = self.busy | start
        self.to_finish = torch.where(self.busy, self.to_finish - tau[:, None], self.to_finish)
        self.to_arrival = self.to_arrival - tau
        lost = torch.zeros_like(tau)
        for _ in range(self._events_per_step):
            kind, gap, new = self._draw_part_type(), self._draw_gap(), self._draw_assembly()
            hit = self.to_arrival <= 0
            arrive = one_hot_mask(kind, n) & hit[:, None]
            lost = lost + (arrive & (self.warehouse > 0)).any(-1).float()
            self.warehouse = torch.where(arrive, 1, self.warehouse)
            self.to_arrival = torch.where(hit, self.to_arrival + gap, self.to_arrival)
            done = self.busy & (self.to_finish <= 0)
            self.drop_off = self.drop_off - done.long()
            self.pick_up = self.pick_up + done.long()
            restart = done & (self.drop_off > 0) & (self.pick_up < CAPACITY)
            self.to_finish = torch.where(restart, self.to_finish + new, self.to_finish)
            self.busy = (self.busy & ~done) | restart
        return lost


def gymnasium_env(render_mode: str | None = None):
    """``gymnasium.make("hrl/AGV-v0")``: one row of the discrete-time ``AGVEnv``."""
    from hrl_torch.env.adapters import BatchedToGymnasium

    return BatchedToGymnasium(lambda seeds, n: AGVEnv(seeds, n), render_mode=render_mode)


def gymnasium_env_continuous(render_mode: str | None = None):
    """``gymnasium.make("hrl/AGVContinuous-v0")``: one row of the continuous-time ``AGVEnv``."""
    from hrl_torch.env.adapters import BatchedToGymnasium

    return BatchedToGymnasium(
        lambda seeds, n: AGVEnv(seeds, n, continuous=True), render_mode=render_mode
    )
