"""The four-AGV scheduling task of Figure 6.2 (Section 6.4, Table 6.1), batched, event-driven.

## Description
Up to four AGVs move raw parts from a warehouse to four workstations M1-M4 and bring the
finished assemblies back. Parts of type ``i`` arrive at the warehouse (mix 20/28/22/30 %) and
wait in bay ``Wi``; an AGV loads one, drops it at ``Di`` (the input buffer of ``Mi``), ``Mi``
assembles its parts one at a time into ``Pi`` (its output buffer), and AGVs load assemblies at
``Pi`` and unload them at ``WA`` (warehouse, assemblies in). The text gives no drawing of the
layout, only "100 locations" and one-way travel; this is a reconstruction with exactly 100.
Travel follows the arrows; ``Forward`` follows the lane the AGV is on (round the corners too),
``Left`` / ``Right`` take the branches at the junctions ``J1``, ``J2`` (left to M1/M2, right to
M3/M4) and ``JE`` (left onto the north loop, right onto the south loop)::

      64 <--- 63 <--------- .. <------------- 56 <--- 55 <-- .. <-- 50 <--- 49 <-- .. <-- 45
      |                                       ^                     ^                     ^
      v 65                                    | 24                  | 29                  | 44
      :                                    P1 23                 P2 28                    :
      v                                  [M1] 22               [M2] 27                    ^
      |                                    D1 21                 D2 26                    | 40
      v 69                                    | 20                  | 25                  |
      WA -> W1 -> W2 -> W3 -> W4 -> .. -----> J1 -----> .. -------> J2 -----> .. -------> JE
      0     1     2     3     4     5-7       8         9-13        14        15-18       19
      ^ 99                                    | 30                  | 35                  | 70
      |                                    D3 31                 D4 36                    |
      ^                                  [M3] 32               [M4] 37                    v
      :                                    P3 33                 P4 38                    :
      ^ 95                                    v 34                  v 39                  | 74
      |                                       v                     v                     v
      94 <--- 93 <--------- .. <------------- 86 <--- 85 <-- .. <-- 80 <--- 79 <-- .. <-- 75

Location indices (a 20 x 13 grid, ``x`` east, ``y`` north): the spine ``y = 0`` is
``0..19`` (``x`` = index: WA 0, W1-W4 1-4, J1 8, J2 14, JE 19); the branches (south to north
for M1/M2, north to south for M3/M4, five locations each) are M1 ``20..24`` (D1 21, P1 23),
M2 ``25..29`` (D2 26, P2 28), M3 ``30..34`` (D3 31, P3 33), M4 ``35..39`` (D4 36, P4 38);
the loops are ``JE`` north ``40..44``, the north lane ``45..64`` (east to west), down to WA
``65..69``, ``JE`` south ``70..74``, the south lane ``75..94``, up to WA ``95..99``. A branch
joins its loop at the lane location above (below) its junction: M1 at 56, M2 at 50, M3 at 86,
M4 at 80. An AGV passes ``Pi`` right after ``Di``. From WA to D1 (D3) is 10 moves, from P1
(P3) back to WA 16; a round from WA through M1 or M3 takes 28 moves, through M2 or M4 40,
round the outer loop 50. AGVs do not collide: any number may share a
location (the text mentions no collisions; all conflicts are over buffer space, see Dynamics).

## Action Space
``Discrete(6)`` per agent: 0 ``Forward``, 1 ``Left``, 2 ``Right`` (a move that has no branch at
the AGV's location does not move, e.g. ``Left`` on a lane or ``Forward`` at ``JE``), 3 ``Load``
(AGV empty: part ``i`` at ``Wi`` if the bay holds one, assembly ``i`` at ``Pi`` if the buffer
holds one), 4 ``Unload`` (part ``i`` at ``Di`` if it has room; any assembly at ``WA``; part
``i`` back into bay ``Wi``, which holds at most one part: a surplus part is lost, so no state is
a dead end), 5 ``Idle`` (wait). An action that cannot apply only takes time. An AGV carries one
item at a time.

## Observation
A TensorDict ``[B]`` (see ``hrl_torch.env.multiagent_env``). Per agent (``"agents"``, ``[B, n]``):
``location`` (100), ``status`` (0 empty, ``i`` carrying part ``i``, ``4 + i`` carrying assembly
``i``; 9 values), ``delivery`` (what the agent's last action delivered: 0 nothing, ``i`` part
``i`` into ``Di``, ``4 + i`` assembly ``i`` into the warehouse; it keeps its value while the
agent's next action runs and drives the subtasks' termination) and ``observation``, the agent's
flat single-agent state in ``[0, 100 * 9 * (c + 1)**8 * 2**4)`` (``943,718,400`` for capacity
``c = 3``, the text's "about 10^9"; mixed radix ``location, status, drop_off_1..4,
pick_up_1..4, warehouse_1..4``, most significant first). Shared: ``drop_off_i`` and
``pick_up_i`` (0..c items in ``Di`` / ``Pi``; the part on the machine counts in ``Di``),
``warehouse_i`` (0/1); the float counts of the step ``assemblies_delivered``,
``parts_delivered`` (parts dropped at their workstation) and ``parts_lost``; and the request
ages the dispatching rules read: ``bay_age`` ``[B, 4]`` (how long the part in ``Wi`` has waited,
0 when the bay is empty) and ``pick_up_age`` ``[B, 4, c]`` (how long each assembly in ``Pi`` has
waited, oldest first, 0 in empty slots). Throughput (Figures 6.4-6.7) is the sum of
``assemblies_delivered`` over a window divided by the window's time (the sum of ``duration``).

## Dynamics
Event-driven continuous time, the tau_continue scheme of Section 6.1 at the level of primitive
actions: every agent runs one primitive action at a time; a step starts the actions of the
agents that are ``acting`` and advances the row's clock to the earliest end among the running
actions; the agents whose actions end then (ties end together) act at the next step. An
action's effect happens at its decision epoch (as in ``envs/agv.py``): a move puts the AGV on
the next location at once, a load or unload changes the buffers at once. Agents acting at the
same epoch are served loads first, then unloads, each in agent order: an agent loads only
what the earlier loads left, and unloads only into the room the earlier unloads left (all with
batched prefix sums over the agents, no loop). Then machines start (``Mi`` starts a part when
``Di`` holds one and ``Pi`` has room: blocking), and arrivals and assembly run until the new
decision epoch. An advance never exceeds the longest action, so each process has a bounded
number of events in it (``1 + floor(longest action / shortest gap)``: 1 with Table 6.1, 2 with
2 s primitives); they are processed in that many rounds, each process in its own time order
(arrivals change only the bays, machines only their buffers, so the processes do not interact
within an advance). An arrival of a type whose bay is full is lost (``parts_lost``). Timers
count down in float64 (``to_end`` per agent, ``to_arrival``, ``to_finish``): no absolute clock,
so 1 ms steps stay accurate after hours of simulated time. Every step draws the same random
numbers whatever the state (a learner's stream does not depend on its population).
Distributions (``FourAGVTiming``; "variance" in
Table 6.1 is read as the variance, std = sqrt(variance)):

* ``Idle``: Normal(1 s, var 0.1); the other primitives: Normal(1 ms, var 0.00005 s^2)
  (``TABLE_6_1``), or Normal(2 s, var 0.1) for Figure 6.5 (``FIGURE_6_5``: the text gives the
  mean only; we keep the ``Idle`` variance).
* inter-arrival: ``Uniform(4 -+ sqrt(3))`` s (variance 1); assembly: Normal(15/24/24/30 s,
  var 2).
* Normals are truncated symmetrically, at ``mean -+ k std`` with ``k = min(6, 0.999 mean /
  std)`` (sampled exactly by the inverse CDF, one uniform per draw), so durations stay positive
  and the mean stays the table's. Only the primitives' table entry is cut hard: its std (7.1 ms)
  is seven times its mean, so the cut is at ``-+0.141 std``, a near-uniform on (1 us, 2 ms) with
  variance about 3.3e-7 s^2 instead of 5e-5 (a positive duration with mean 1 ms cannot come
  from a symmetric truncation of that normal). ``Idle`` is cut at ``-+3.16 std`` (variance
  0.098).

## Rewards
``AGVRewards`` (from ``envs.agv``), a team reward: lump reward ``k`` (+1 per assembly unloaded
at ``WA`` by default, an optional amount per part dropped at its workstation) plus a reward rate
times the step's duration (default 0). With the defaults the gain is the throughput.

## Starting State
Every AGV empty at ``WA``; buffers and warehouse empty; machines idle; first arrival one
inter-arrival time away; every agent acts at the first step.

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
from envs.agv import AGVRewards
from hrl_torch.common.ops import one_hot_mask
from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv


# -- layout
def _build_layout() -> tuple[tuple[str, ...], list[tuple[int, int, int]]]:
    """Names and ``(forward, left, right)`` successors of the 100 locations (None: stay)."""
    names = [str(k) for k in range(100)]
    succ: list[list[int | None]] = [[None, None, None] for _ in range(100)]

    def lane(cells: Sequence[int], then: int) -> None:
        for a, b in zip(cells, [*cells[1:], then], strict=True):
            succ[a][0] = b

    lane(range(0, 19), 19)  # spine WA .. JE
    for k, name in enumerate(("WA", "W1", "W2", "W3", "W4")):
        names[k] = name
    names[8], names[14], names[19] = "J1", "J2", "JE"
    north, south = range(45, 65), range(75, 95)
    for i, (first, x, up) in enumerate(((20, 8, 1), (25, 14, 1), (30, 8, 0), (35, 14, 0))):
        joins = north[19 - x] if up else south[19 - x]  # the loop location above / below
        lane(range(first, first + 5), joins)
        names[first + 1], names[first + 3] = f"D{i + 1}", f"P{i + 1}"
        succ[x][1 if up else 2] = first  # J1 / J2: Left to M1 / M2, Right to M3 / M4
    succ[19][1], succ[19][2] = 40, 70
    lane(range(40, 45), 45)  # JE north to the NE corner
    lane(north, 65)
    lane(range(65, 70), 0)  # down to WA
    lane(range(70, 75), 75)  # JE south to the SE corner
    lane(south, 95)
    lane(range(95, 100), 0)  # up to WA
    names[45], names[64], names[75], names[94] = "NE", "NW", "SE", "SW"
    table = [tuple(k if s is None else s for s in row) for k, row in enumerate(succ)]
    return tuple(names), table  # type: ignore[return-value]


LOCATION_NAMES, _SUCCESSORS = _build_layout()
N_LOCATIONS = len(LOCATION_NAMES)
LOC = {name: k for k, name in enumerate(LOCATION_NAMES)}
N_STATIONS = 4
CAPACITY = 3
DROP_OFF = tuple(LOC[f"D{i}"] for i in range(1, 5))
PICK_UP = tuple(LOC[f"P{i}"] for i in range(1, 5))
BAYS = tuple(LOC[f"W{i}"] for i in range(1, 5))
WAREHOUSE_DROP = LOC["WA"]
START = LOC["WA"]
N_STATUS = 1 + 2 * N_STATIONS
EMPTY = 0
FORWARD, LEFT, RIGHT, LOAD, UNLOAD, IDLE = range(6)
N_ACTIONS = 6
ACTION_NAMES = ("Forward", "Left", "Right", "Load", "Unload", "Idle")
N_MOVES = 3


def successors() -> torch.Tensor:
    """``[100, 3]`` next location for ``Forward`` / ``Left`` / ``Right`` (no branch: stay)."""
    return torch.tensor(_SUCCESSORS)


def station_of(locations: Sequence[int]) -> torch.Tensor:
    """``[100]`` long: ``i`` at ``locations[i]``, -1 elsewhere."""
    return common.station_of(N_LOCATIONS, locations)


@lru_cache(maxsize=1)
def shortest_paths() -> tuple[torch.Tensor, torch.Tensor]:
    """``(distance, first_move)`` ``[100, 100]`` (``[from, to]``; ``envs.agv_common``).

    The first move is ``FORWARD``/``LEFT``/``RIGHT``, the first in that order among equally
    short ones; the layout must be strongly connected.
    """
    return common.shortest_paths(successors())


# -- flat single-agent state index
def radices(capacity: int = CAPACITY) -> tuple[int, ...]:
    """Radices of the flat state: location, status, 8 buffers, 4 warehouse bits."""
    return common.radices(N_LOCATIONS, N_STATIONS, capacity)


def n_flat_states(capacity: int = CAPACITY) -> int:
    """Size of one agent's flat state space: ``100 * 9 * (c + 1)**8 * 2**4``."""
    return math.prod(radices(capacity))


def encode(location, status, drop_off, pick_up, warehouse, capacity: int = CAPACITY):
    """Flat state index (mixed radix, most significant first).

    Args:
        location: ``[...]`` in ``[0, 100)``.
        status: ``[...]`` in ``[0, 9)``.
        drop_off: ``[..., 4]`` in ``[0, capacity]``.
        pick_up: ``[..., 4]`` in ``[0, capacity]``.
        warehouse: ``[..., 4]`` in ``{0, 1}``.
        capacity: buffer capacity ``c``.
    """
    return common.encode(radices(capacity), location, status, drop_off, pick_up, warehouse)


@lru_cache(maxsize=8)
def place_values(capacity: int = CAPACITY) -> torch.Tensor:
    """``[14]`` long: the weight of each digit of the flat state index."""
    r = radices(capacity)
    return torch.tensor([math.prod(r[k + 1 :]) for k in range(len(r))])


def decode(index: torch.Tensor, capacity: int = CAPACITY) -> dict[str, torch.Tensor]:
    """Observation fields (``location``, ``status``, the buffers) of flat indices (any shape)."""
    return common.decode(radices(capacity), index)


# -- model parameters
@dataclass(frozen=True)
class FourAGVTiming:
    """Time model: means and variances of Table 6.1 (seconds; variances in s^2).

    Attributes:
        action_mean: mean duration of ``Forward``/``Left``/``Right``/``Load``/``Unload``.
        action_var: its variance.
        idle_mean: mean duration of ``Idle``.
        idle_var: its variance.
        interarrival_mean: mean time between part arrivals (uniform distribution).
        interarrival_var: its variance.
        assembly_mean: mean assembly time per part type.
        assembly_var: variance of the assembly times.
        part_mix: probability of each part type in the arrival stream.
    """

    action_mean: float = 0.001
    action_var: float = 0.00005
    idle_mean: float = 1.0
    idle_var: float = 0.1
    interarrival_mean: float = 4.0
    interarrival_var: float = 1.0
    assembly_mean: tuple[float, ...] = (15.0, 24.0, 24.0, 30.0)
    assembly_var: float = 2.0
    part_mix: tuple[float, ...] = (0.20, 0.28, 0.22, 0.30)


#: Table 6.1 (Figures 6.4, 6.6, 6.7, 6.8)
TABLE_6_1 = FourAGVTiming()
#: Figure 6.5: primitives take 2 s on average (the text gives no variance: ``Idle``'s 0.1)
FIGURE_6_5 = FourAGVTiming(action_mean=2.0, action_var=0.1)
_TRUNCATE = 6.0  # normals are cut at mean -+ 6 std at most


class _TruncatedNormal:
    """Normal(mean, var) cut symmetrically at ``mean -+ k std``, ``k = min(6, 0.999 mean/std)``.

    Sampled by the inverse CDF from one uniform per value (float64), so the mean is exact and
    every value is positive. ``mean`` may be a tuple (one distribution per column).
    """

    def __init__(self, mean, var: float, device: torch.device) -> None:
        self.mean = torch.tensor(mean, dtype=torch.float64, device=device)
        self.std = math.sqrt(var)
        cut = (0.999 * self.mean / self.std).clamp_max(_TRUNCATE)
        self.low, self.high = self.mean - cut * self.std, self.mean + cut * self.std  # support
        self._p_low = torch.special.ndtr(-cut)
        self._p_width = torch.special.ndtr(cut) - self._p_low

    def __call__(self, u: torch.Tensor) -> torch.Tensor:
        """Values for uniforms ``u`` in ``[0, 1)`` (shape kept; float64)."""
        p = self._p_low + self._p_width * (u.double() + 0.5 / 16777216.0)
        return self.mean + self.std * torch.special.ndtri(p)


class FourAGVEnv(MultiAgentBatchedEnv):
    """Torch-batched multi-agent AGV scheduling task (see the module docstring).

    Args:
        seeds: one seed per learner.
        envs_per_learner: envs per learner ``E``; the batch is ``len(seeds) * E``.
        n_agents: AGVs per env (1 gives the single-agent task).
        capacity: room of every buffer ``Di`` / ``Pi`` (3 in the text, 1 for Figure 6.6).
        timing: time model (``TABLE_6_1``, or ``FIGURE_6_5`` for 2 s primitives).
        rewards: team reward definition.
        max_episode_steps: optional time limit in decision epochs (none: a continuing task).
        device: where the state lives.
        own_rewards: each agent's reward is its own deliveries (their sum is the team reward);
            otherwise every agent receives the team's.
    """

    state_keys = (
        "location",
        "status",
        "delivery",
        "to_end",
        "drop_off",
        "pick_up",
        "warehouse",
        "busy",
        "to_finish",
        "to_arrival",
        "bay_age",
        "pick_up_age",
        "delivered",
        "parts_in",
        "lost",
    )
    agent_observation_sizes = {"location": N_LOCATIONS, "status": N_STATUS, "delivery": N_STATUS}

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        n_agents: int = 4,
        capacity: int = CAPACITY,
        timing: FourAGVTiming = TABLE_6_1,
        rewards: AGVRewards | None = None,
        max_episode_steps: int | None = None,
        device: torch.device | str = "cpu",
        own_rewards: bool = False,
    ) -> None:
        super().__init__(seeds, envs_per_learner, n_agents, N_ACTIONS, max_episode_steps, device)
        self.own_rewards = own_rewards
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        n, dev, t = N_STATIONS, self.device, timing
        if len(t.assembly_mean) != n or len(t.part_mix) != n:
            raise ValueError(f"timing needs {n} assembly means and part fractions")
        self.capacity = int(capacity)
        self.timing = timing
        self.rewards = rewards or AGVRewards()
        self.observation_sizes = {
            **{f"{k}_{i + 1}": capacity + 1 for k in ("drop_off", "pick_up") for i in range(n)},
            **{f"warehouse_{i + 1}": 2 for i in range(n)},
        }
        self.agent_observation_sizes = {
            **type(self).agent_observation_sizes,
            "observation": n_flat_states(capacity),
        }
        self.succ = successors().to(dev)
        self.drop_station = station_of(DROP_OFF).to(dev)
        self.pick_station = station_of(PICK_UP).to(dev)
        self.bay_type = station_of(BAYS).to(dev)
        self._slots = torch.arange(capacity, device=dev)
        self._place_values = place_values(capacity).to(dev)
        self._set_distributions()
        b, shape, f64 = self.batch_size, (self.batch_size, self.n_agents), torch.float64
        self.location = torch.full(shape, START, dtype=torch.long, device=dev)
        self.status = torch.zeros(shape, dtype=torch.long, device=dev)
        self.delivery = torch.zeros(shape, dtype=torch.long, device=dev)
        self.to_end = torch.zeros(shape, dtype=f64, device=dev)
        self.drop_off = torch.zeros(b, n, dtype=torch.long, device=dev)
        self.pick_up = torch.zeros(b, n, dtype=torch.long, device=dev)
        self.warehouse = torch.zeros(b, n, dtype=torch.long, device=dev)
        self.busy = torch.zeros(b, n, dtype=torch.bool, device=dev)
        self.to_finish = torch.zeros(b, n, dtype=f64, device=dev)
        self.to_arrival = torch.zeros(b, dtype=f64, device=dev)
        self.bay_age = torch.zeros(b, n, dtype=f64, device=dev)
        self.pick_up_age = torch.zeros(b, n, capacity, dtype=f64, device=dev)
        self.delivered = torch.zeros(b, device=dev)
        self.parts_in = torch.zeros(b, device=dev)
        self.lost = torch.zeros(b, device=dev)

    # -- distributions (each draws for every row, whatever the state)
    def _set_distributions(self) -> None:
        """The truncated normals, the uniform's support and the events per advance."""
        t, dev = self.timing, self.device
        means = (t.action_mean, t.idle_mean, t.interarrival_mean, *t.assembly_mean)
        if min(means) <= 0 or abs(sum(t.part_mix) - 1.0) > 1e-6:
            raise ValueError(f"timing needs positive means and a part mix summing to 1: {t}")
        self._move_time = _TruncatedNormal(t.action_mean, t.action_var, dev)
        self._idle_time = _TruncatedNormal(t.idle_mean, t.idle_var, dev)
        self._assembly_time = _TruncatedNormal(t.assembly_mean, t.assembly_var, dev)
        half = math.sqrt(3.0 * t.interarrival_var)
        self._gap_bounds = (t.interarrival_mean - half, t.interarrival_mean + half)
        if self._gap_bounds[0] <= 0:
            raise ValueError(f"inter-arrival times must stay positive: {t}")
        self._mix_cdf = torch.tensor(t.part_mix, device=dev).cumsum(0)[:-1]
        # events of one process in an advance are >= the shortest gap apart, and an advance is
        # at most the longest action: at most 1 + floor(longest / shortest) of them
        longest = max(float(self._move_time.high.max()), float(self._idle_time.high.max()))
        shortest = min(self._gap_bounds[0], float(self._assembly_time.low.min()))
        self._events_per_step = 1 + math.floor(longest / shortest)

    def _draw_action_time(self, action: torch.Tensor) -> torch.Tensor:
        """Durations ``[B, n]`` (float64) of the actions ``[B, n]`` if they start now."""
        u = self.rng.uniform(self.n_agents)
        return torch.where(action == IDLE, self._idle_time(u), self._move_time(u))

    def _draw_gap(self) -> torch.Tensor:
        low, high = self._gap_bounds
        return low + (high - low) * self.rng.uniform().double()

    def _draw_assembly(self) -> torch.Tensor:
        """Assembly times ``[B, 4]`` (float64)."""
        return self._assembly_time(self.rng.uniform(N_STATIONS))

    def _draw_part_type(self) -> torch.Tensor:
        return (self.rng.uniform()[:, None] >= self._mix_cdf).sum(-1)

    # -- MultiAgentBatchedEnv hooks
    def _reset_rows(self, mask: torch.Tensor) -> None:
        gap = self._draw_gap()
        m2 = mask[:, None]
        self.location = torch.where(m2, START, self.location)
        for name in ("status", "delivery", "to_end", "drop_off", "pick_up", "warehouse"):
            setattr(self, name, torch.where(m2, 0, getattr(self, name)))
        for name in ("to_finish", "bay_age"):
            setattr(self, name, torch.where(m2, 0.0, getattr(self, name)))
        self.busy = self.busy & ~m2
        self.pick_up_age = torch.where(m2[:, :, None], 0.0, self.pick_up_age)
        for name in ("delivered", "parts_in", "lost"):
            setattr(self, name, torch.where(mask, 0.0, getattr(self, name)))
        self.to_arrival = torch.where(mask, gap, self.to_arrival)

    def _step_all(self, action: torch.Tensor, acting: torch.Tensor):  # type: ignore[override]
        action = action.long()
        tau = self._draw_action_time(action)
        assemblies, parts, returned_lost = self._act(action, acting)
        self.to_end = torch.where(acting, tau, self.to_end)
        self._start_machines()
        dt = self.to_end.min(1).values
        self.to_end = self.to_end - dt[:, None]
        next_acting = self.to_end <= 0
        self.lost = returned_lost + self._advance(dt)
        self.delivered, self.parts_in = assemblies, parts
        r = self.rewards
        reward = r.assembly * assemblies + r.part * parts + r.rate * dt.float()
        if self.own_rewards:  # each agent's own deliveries (their sum is the team's reward)
            own_assemblies, own_parts = self._own
            rate = r.rate * dt.float()[:, None] / self.n_agents
            reward = r.assembly * own_assemblies + r.part * own_parts + rate
        terminated = torch.zeros(self.batch_size, dtype=torch.bool, device=self.device)
        return reward, dt, terminated, next_acting

    def _observe(self) -> dict[str, torch.Tensor]:
        fields: dict[str, torch.Tensor] = {}
        for i in range(N_STATIONS):
            fields[f"drop_off_{i + 1}"] = self.drop_off[:, i].clone()
            fields[f"pick_up_{i + 1}"] = self.pick_up[:, i].clone()
            fields[f"warehouse_{i + 1}"] = self.warehouse[:, i].clone()
        fields.update(
            assemblies_delivered=self.delivered.clone(),
            parts_delivered=self.parts_in.clone(),
            parts_lost=self.lost.clone(),
            bay_age=self.bay_age.float(),
            pick_up_age=self.pick_up_age.float(),
        )
        return fields

    def _observe_agents(self) -> dict[str, torch.Tensor]:
        weights = self._place_values
        buffers = torch.cat([self.drop_off, self.pick_up, self.warehouse], -1)
        shared = (buffers * weights[2:]).sum(-1, keepdim=True)
        flat = self.location * weights[0] + self.status * weights[1] + shared
        return {
            "location": self.location.clone(),
            "status": self.status.clone(),
            "delivery": self.delivery.clone(),
            "observation": flat,
        }

    # -- dynamics
    def _act(self, action: torch.Tensor, acting: torch.Tensor):
        """Apply the acting agents' actions at the decision epoch (loads first, then unloads).

        Returns:
            ``(assemblies delivered, parts dropped at workstations, parts lost by returning them
            to a full bay)``, each ``[B]`` float.
        """
        loc, status, n, cap = self.location, self.status, N_STATIONS, self.capacity
        bay, pick, drop = self.bay_type[loc], self.pick_station[loc], self.drop_station[loc]

        def requests(station: torch.Tensor, when: torch.Tensor) -> torch.Tensor:
            """``[B, agents, 4]`` long: agent ``j`` asks station ``station[b, j]``."""
            return (
                one_hot_mask(station.clamp_min(0), n) & (when & (station >= 0))[..., None]
            ).long()

        def served(asks: torch.Tensor, amount: torch.Tensor) -> torch.Tensor:
            """The asks an agent-ordered queue can serve from ``amount [B, 4]`` units."""
            return asks * (asks.cumsum(1) <= amount[:, None, :])

        # loads: an empty AGV takes part i at Wi or assembly i at Pi, if one is left for it
        load = acting & (action == LOAD) & (status == EMPTY)
        got_part = served(requests(bay, load), self.warehouse)
        got_asm = served(requests(pick, load), self.pick_up)
        taken = got_asm.sum(1)
        self.warehouse = self.warehouse - got_part.sum(1)
        self.pick_up = self.pick_up - taken
        self.bay_age = torch.where(self.warehouse > 0, self.bay_age, 0.0)
        self._pop_pick_up_ages(taken)
        status = torch.where(got_part.any(-1), 1 + bay, status)
        status = torch.where(got_asm.any(-1), 1 + n + pick, status)

        # unloads: part i into Di (if room is left), part i back into Wi, assemblies at WA
        unload = acting & (action == UNLOAD)
        part = torch.where((status >= 1) & (status <= n), status - 1, -1)
        dropped = served(requests(drop, unload & (drop == part)), cap - self.drop_off)
        returns = requests(bay, unload & (bay == part))
        kept = served(returns, 1 - self.warehouse)  # the bay holds one part at most
        deliver = unload & (status > n) & (loc == WAREHOUSE_DROP)
        self.drop_off = self.drop_off + dropped.sum(1)
        self.warehouse = self.warehouse + kept.sum(1)
        dropped_any, returned = dropped.any(-1), returns.any(-1)
        self.delivery = torch.where(
            acting, torch.where(dropped_any | deliver, status, 0), self.delivery
        )
        self.status = torch.where(dropped_any | returned | deliver, EMPTY, status)
        moved = self.succ[loc, action.clamp(0, N_MOVES - 1)]
        self.location = torch.where(acting & (action < N_MOVES), moved, loc)
        lost = (returns.sum((1, 2)) - kept.sum((1, 2))).float()
        self._own = (deliver.float(), dropped.sum(2).float())  # each agent's [B, n]
        return deliver.sum(1).float(), dropped.sum((1, 2)).float(), lost

    def _pop_pick_up_ages(self, taken: torch.Tensor) -> None:
        """Remove the ``taken [B, 4]`` oldest assemblies' ages from the ``Pi`` queues."""
        cap = self.capacity
        source = self._slots + taken[:, :, None]  # slot s gets the age of slot s + taken
        ages = self.pick_up_age.gather(2, source.clamp_max(cap - 1))
        self.pick_up_age = torch.where(source < cap, ages, 0.0)

    def _start_machines(self) -> None:
        """Idle machines with a part in ``Di`` and room in ``Pi`` start it now."""
        new = self._draw_assembly()
        start = ~self.busy & (self.drop_off > 0) & (self.pick_up < self.capacity)
        self.to_finish = torch.where(start, new, self.to_finish)
        self.busy = self.busy | start

    def _advance(self, dt: torch.Tensor) -> torch.Tensor:
        """Run arrivals and assembly for ``dt [B]``; return the arrivals lost to full bays.

        Timers are decremented first; an event that fired ``x`` seconds before the end of the
        advance leaves its timer at ``-x``, which is also the age of what it produced.
        """
        n, cap = N_STATIONS, self.capacity
        self.to_finish = torch.where(self.busy, self.to_finish - dt[:, None], self.to_finish)
        self.to_arrival = self.to_arrival - dt
        self.bay_age = torch.where(self.warehouse > 0, self.bay_age + dt[:, None], 0.0)
        queued = self._slots < self.pick_up[:, :, None]
        self.pick_up_age = torch.where(queued, self.pick_up_age + dt[:, None, None], 0.0)
        lost = torch.zeros(self.batch_size, device=self.device)
        for _ in range(self._events_per_step):
            kind, gap, new = self._draw_part_type(), self._draw_gap(), self._draw_assembly()
            hit = self.to_arrival <= 0
            arrive = one_hot_mask(kind, n) & hit[:, None]
            stored = arrive & (self.warehouse == 0)
            lost = lost + (arrive & ~stored).any(-1).float()
            self.bay_age = torch.where(stored, -self.to_arrival[:, None], self.bay_age)
            self.warehouse = torch.where(arrive, 1, self.warehouse)
            self.to_arrival = torch.where(hit, self.to_arrival + gap, self.to_arrival)
            done = self.busy & (self.to_finish <= 0)
            slot = done[:, :, None] & (self._slots == self.pick_up[:, :, None])
            self.pick_up_age = torch.where(slot, -self.to_finish[:, :, None], self.pick_up_age)
            self.drop_off = self.drop_off - done.long()
            self.pick_up = self.pick_up + done.long()
            restart = done & (self.drop_off > 0) & (self.pick_up < cap)
            self.to_finish = torch.where(restart, self.to_finish + new, self.to_finish)
            self.busy = (self.busy & ~done) | restart
        return lost
