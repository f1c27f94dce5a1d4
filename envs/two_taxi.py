"""Taxis serving a continuing stream of passengers (Section 6.6, Figure 6.10), batched.

## Description
Dietterich's 5x5 taxi grid with its walls and the stations R(0,0), G(0,4), Y(4,0), B(4,3)
(``envs.taxi``)::

    +---------+
    |R: | : :G|
    | : | : : |
    | : : : : |
    | | : | : |
    |Y| : |B: |
    +---------+

``n_agents`` taxis (default 2, T1 and T2 in the text) share the grid; they never block each
other. The task is continuing: passengers appear at the stations and wish to go to one of the
*other* three stations, chosen uniformly. Each station holds at most one waiting passenger
(its status has 4 values: empty, or a passenger for one of the other three stations); an
arrival at an occupied station is lost (``n_lost``). A taxi carries at most one passenger (its
status has 5 values: empty, or carrying a passenger to one of the 4 stations).

**Arrival rate.** The text's rates are 5, 10 and 20 and its footnote 4 defines them: "passenger
arrival rate 10 indicates that on average, one passenger arrives at stations every 10 time
steps". So the rate is a *mean inter-arrival time over the whole grid*, in steps:
``mean_interarrival`` (default 10). At every step one passenger arrives with probability
``1 / mean_interarrival`` (at most one per step: a Bernoulli process, geometric gaps of that
mean) at a uniformly chosen station. Rate 5 is thus the busiest setting and rate 20 the
quietest; the prose around Figure 6.13 ("as the arrival rate becomes smaller, coordination
becomes more important") speaks of frequency, i.e. of larger numbers here.
``mean_interarrival=float("inf")`` turns arrivals off.

The footnote's "at stations" also reads *per station*: ``arrivals="station"`` gives every
station its own Bernoulli process of mean gap ``mean_interarrival`` (the grid then sees four
times as many arrivals; up to four in one step). ``arrivals="grid"`` (the default, above) is
the original reading; both are measured in ``docs/reproduction.md``.

**One step**, in this order: every passenger waiting at a station waits one more step; the
taxis act at once (moves; pickups, a station's passenger going to the lowest-index taxi that
picks up there; putdowns); then the step's arrival, if any (a station emptied by a pickup of
this step can take it; per station, every station's own arrival).

## Action Space
``Discrete(7)`` per taxi: 0 south, 1 north, 2 east, 3 west, 4 pickup, 5 putdown (the numbering
of ``envs.taxi``) and 6 wait (idle), the primitive of the Wait subtask of Figure 6.10.
``pickup`` is legal for an empty taxi at a station with a waiting passenger; when another taxi
of lower index takes that passenger in the same step the pickup just does nothing. ``putdown``
is legal only at the carried passenger's destination, which delivers the passenger; elsewhere
(other stations included) it does nothing and is penalised: a station only holds passengers
who have just arrived.

The text counts "the number of primitive actions 10" for the flat joint Q table (4 x 10^6
states x 10). No product of per-taxi action sets gives 10 (6 x 6 = 36 joint actions without
Wait, 7 x 7 = 49 with it); 10 = 2 x 5 is the *sum* over two taxis of five actions each (four
moves and one load/unload), the size of a table with one action of one taxi per column. Here a
flat joint table would have 4 x 10^6 x 49 entries (1.96 x 10^8), a flat per-taxi table over
the joint state 4 x 10^6 x 7.

## Observation
A TensorDict ``[B]`` (``hrl_torch.env.multiagent_env``). Shared fields: ``observation`` (joint state
index, ``125**n * 256`` values: 4,000,000 for two taxis, the text's "4 x 10^6"),
``stations`` (``sum_s code_s * 4**s``, 256 values) and ``waiting_R``, ``waiting_G``,
``waiting_Y``, ``waiting_B`` (the station codes: 0 empty, ``c`` in 1-3 a passenger for the
``c``-th other station in R, G, Y, B order; ``destination_of_code``). Per-step metrics
(undeclared fields): ``n_arrived`` (passengers that appeared, lost ones included), ``n_lost``,
``n_picked_up``, ``n_delivered``, ``wait_delivered`` (sum over the passengers delivered at this
step of their waiting time, from arrival to pickup, in steps) and ``n_waiting`` (passengers
waiting after the step). Per taxi (``"agents"`` ``[B, n]``): ``taxi_loc`` (25), ``taxi_row``,
``taxi_col`` (5), ``status`` (0-3 carrying a passenger to that station, 4 empty),
``own_state`` (``(taxi_loc * 5 + status) * 256 + stations``, 32,000 values: what one taxi
stores), ``picked_up`` / ``delivered`` (1 when this taxi picked up / delivered at this step)
and ``last_action`` (0-6, 7 after a reset).

Waiting time: a passenger who arrives at step ``t`` is seen from the observation after it; if a
taxi picks it up at step ``t + k``, its waiting time is ``k``. Average waiting time per
passenger over a window: ``sum(wait_delivered) / sum(n_delivered)`` (``average_wait``);
throughput: deliveries per 5,000 steps (``throughput``).

## Rewards
A team reward that makes throughput and waiting matter: +20 per delivery, -1 per step for every
passenger waiting at a station at the start of the step (so each passenger costs its waiting
time in all: the sum of the waits), -10 per illegal pickup or putdown. Moving and waiting cost
nothing (in a continuing task a constant cost per step changes no policy's ranking).

## Starting State
No passengers; every taxi empty on an independent uniformly random square.

## Episode End
None: the task is continuing (never terminated; no time limit unless one is asked for).

## Version History
* v0: Section 6.6; the arrival process per footnote 4, the rewards, the tie rules and the
  order within a step are our choices (the text gives none of them).
* ``arrivals="station"`` added (footnote 4 read per station); ``own_rewards=False`` (one team
  reward for both taxis) is what the text's task ``two-taxi`` uses.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from envs.taxi import DROPOFF, EAST, MAP, NORTH, PICKUP, SOUTH, STATIONS, WEST
from hrl_torch.common.ops import one_hot_mask
from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv

N_LOCATIONS = 25
N_STATIONS = 4
STATION_NAMES = "RGYB"
N_ACTIONS = 7
WAIT = 6
NO_ACTION = N_ACTIONS  # ``last_action`` after a reset
PUTDOWN = DROPOFF
EMPTY = 4  # taxi status: no passenger (0-3: carrying a passenger to that station)
N_STATUS = 5
NO_PASSENGER = N_STATIONS  # stored destination of an empty station
N_STATION_CODES = 4
N_STATIONS_STATES = N_STATION_CODES**N_STATIONS  # 256
N_OWN_STATES = N_LOCATIONS * N_STATUS * N_STATIONS_STATES  # 32,000
DELIVERY_REWARD = 20.0
WAITING_COST = 1.0
ILLEGAL_COST = 10.0
MEAN_INTERARRIVAL = 10.0
#: readings of footnote 4: one arrival process over the grid, or one per station
ARRIVALS = ("grid", "station")
#: the text's window for throughput
THROUGHPUT_WINDOW = 5_000


def _moves() -> torch.Tensor:
    """``[25, 7]`` next location of every action (non-moves stay), from ``envs.taxi.MAP``."""
    moves = torch.arange(N_LOCATIONS).repeat(N_ACTIONS, 1).T.contiguous()
    for row in range(5):
        for col in range(5):
            loc = row * 5 + col
            moves[loc, SOUTH] = min(row + 1, 4) * 5 + col
            moves[loc, NORTH] = max(row - 1, 0) * 5 + col
            if MAP[1 + row][2 * col + 2] == ":":
                moves[loc, EAST] = loc + 1
            if MAP[1 + row][2 * col] == ":":
                moves[loc, WEST] = loc - 1
    return moves


MOVES = _moves()
STATION_LOC = torch.tensor([r * 5 + c for r, c in STATIONS])
#: station at every location (``N_STATIONS`` where there is none)
STATION_AT = torch.full((N_LOCATIONS,), N_STATIONS, dtype=torch.long)
STATION_AT[STATION_LOC] = torch.arange(N_STATIONS)


def station_code(destination: torch.Tensor) -> torch.Tensor:
    """Codes ``[..., 4]`` of stored destinations ``[..., 4]`` (``NO_PASSENGER`` -> 0).

    Station ``s``'s passenger for station ``d != s`` has code ``1 + d - (d > s)``.
    """
    s = torch.arange(N_STATIONS, device=destination.device)
    code = 1 + destination - (destination > s).long()
    return torch.where(destination == NO_PASSENGER, 0, code)


def destination_of_code(station: int | torch.Tensor, code: torch.Tensor) -> torch.Tensor:
    """Inverse of ``station_code``: the destination of code ``code`` (1-3) at ``station``."""
    other = code - 1
    return other + (other >= station).long()


def throughput(n_delivered: torch.Tensor) -> torch.Tensor:
    """Deliveries per 5,000 steps from ``n_delivered [T, ...]`` recorded over ``T`` steps."""
    return n_delivered.sum(0).double() * (THROUGHPUT_WINDOW / n_delivered.shape[0])


def average_wait(n_delivered: torch.Tensor, wait_delivered: torch.Tensor) -> torch.Tensor:
    """Average waiting time per delivered passenger over a window ``[T, ...]`` (NaN if none)."""
    return wait_delivered.sum(0).double() / n_delivered.sum(0).double()


class TwoTaxiEnv(MultiAgentBatchedEnv):
    """Torch-batched multi-taxi domain (see the module docstring).

    Discrete time: every taxi acts at every step.

    Args:
        seeds: one seed per learner.
        envs_per_learner: envs per learner ``E``; the batch is ``len(seeds) * E``.
        n_agents: taxis per env row.
        mean_interarrival: the text's "passenger arrival rate": mean steps between arrivals
            over the whole grid (>= 1; ``inf`` for no arrivals).
        max_episode_steps: optional time limit; the task itself is continuing (default none).
        arrivals: ``"grid"``: at most one arrival per step, at a uniform station (rate over
            the grid); ``"station"``: every station has its own arrival process of that rate.
        own_rewards: each taxi's reward is its own share of the team reward (``[B, n]``, their
            sum is the team's): its own deliveries and illegal actions, and an equal share of
            the waiting cost.
        device: where the state lives.
    """

    state_keys = (
        "taxi_loc",
        "status",
        "taxi_wait",
        "station_dest",
        "station_age",
        "picked_up",
        "delivered",
        "last_action",
        "n_arrived",
        "n_lost",
        "wait_delivered",
    )
    agent_observation_sizes = {
        "taxi_loc": N_LOCATIONS,
        "taxi_row": 5,
        "taxi_col": 5,
        "status": N_STATUS,
        "own_state": N_OWN_STATES,
        "picked_up": 2,
        "delivered": 2,
        "last_action": N_ACTIONS + 1,
    }

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        n_agents: int = 2,
        mean_interarrival: float = MEAN_INTERARRIVAL,
        max_episode_steps: int | None = None,
        own_rewards: bool = False,
        device: torch.device | str = "cpu",
        arrivals: str = "grid",
    ) -> None:
        super().__init__(seeds, envs_per_learner, n_agents, N_ACTIONS, max_episode_steps, device)
        self.own_rewards = own_rewards
        if arrivals not in ARRIVALS:
            raise ValueError(f"arrivals must be one of {ARRIVALS}, got {arrivals!r}")
        self.arrivals = arrivals
        if not mean_interarrival >= 1.0:
            raise ValueError(f"mean_interarrival must be >= 1 steps, got {mean_interarrival}")
        self.mean_interarrival = float(mean_interarrival)
        self.arrival_prob = 1.0 / self.mean_interarrival
        self.observation_sizes = {
            "observation": (N_LOCATIONS * N_STATUS) ** self.n_agents * N_STATIONS_STATES,
            "stations": N_STATIONS_STATES,
            **{f"waiting_{name}": N_STATION_CODES for name in STATION_NAMES},
        }
        b, shape, dev = self.batch_size, (self.batch_size, self.n_agents), self.device
        long = dict(dtype=torch.long, device=dev)
        self.taxi_loc = torch.zeros(shape, **long)
        self.status = torch.full(shape, EMPTY, **long)
        self.taxi_wait = torch.zeros(shape, **long)  # waiting time of the passenger on board
        self.station_dest = torch.full((b, N_STATIONS), NO_PASSENGER, **long)
        self.station_age = torch.zeros((b, N_STATIONS), **long)  # steps waited so far
        self.picked_up = torch.zeros(shape, dtype=torch.bool, device=dev)
        self.delivered = torch.zeros(shape, dtype=torch.bool, device=dev)
        self.last_action = torch.full(shape, NO_ACTION, **long)
        self.n_arrived = torch.zeros(b, **long)
        self.n_lost = torch.zeros(b, **long)
        self.wait_delivered = torch.zeros(b, **long)
        self._moves = MOVES.to(dev)
        self._station_at = STATION_AT.to(dev)

    def _reset_rows(self, mask: torch.Tensor) -> None:
        start = self.rng.integers(N_LOCATIONS, extra=self.n_agents)  # drawn for every row
        m2 = mask[:, None]
        self.taxi_loc = torch.where(m2, start, self.taxi_loc)
        self.status = torch.where(m2, EMPTY, self.status)
        self.taxi_wait = torch.where(m2, 0, self.taxi_wait)
        self.station_dest = torch.where(m2, NO_PASSENGER, self.station_dest)
        self.station_age = torch.where(m2, 0, self.station_age)
        self.picked_up = self.picked_up & ~m2
        self.delivered = self.delivered & ~m2
        self.last_action = torch.where(m2, NO_ACTION, self.last_action)
        for key in ("n_arrived", "n_lost", "wait_delivered"):
            setattr(self, key, torch.where(mask, 0, getattr(self, key)))

    def _step_all(self, action: torch.Tensor, acting: torch.Tensor):  # type: ignore[override]
        u = self.rng.uniform(3)  # arrival, its station, its destination: drawn for every row
        waiting = self.station_dest != NO_PASSENGER
        self.station_age = self.station_age + waiting.long()
        waiting_cost = WAITING_COST * waiting.sum(1)

        # the taxis act: pickups (lowest index first at each station), putdowns, moves
        here = self._station_at[self.taxi_loc]  # [B, n], N_STATIONS off the stations
        none = torch.full_like(self.station_dest[:, :1], NO_PASSENGER)
        dest_here = torch.cat([self.station_dest, none], 1).gather(1, here)
        age_here = torch.cat([self.station_age, torch.zeros_like(none)], 1).gather(1, here)
        empty = self.status == EMPTY
        pickup, putdown = action == PICKUP, action == PUTDOWN
        legal_pickup = pickup & empty & (dest_here != NO_PASSENGER)
        claims = one_hot_mask(here, N_STATIONS + 1)[..., :N_STATIONS] & legal_pickup[..., None]
        wins = claims & (claims.long().cumsum(1) == 1)  # [B, n, 4]
        picked, taken = wins.any(2), wins.any(1)
        delivered = putdown & ~empty & (here == self.status)
        illegal = (pickup & ~legal_pickup) | (putdown & ~delivered)
        own = DELIVERY_REWARD * delivered.float() - ILLEGAL_COST * illegal.float()  # [B, n]
        if self.own_rewards:  # each taxi's own share; their sum is the team's reward
            reward = own - (waiting_cost / self.n_agents)[:, None]
        else:
            reward = own.sum(1) - waiting_cost
        self.wait_delivered = (self.taxi_wait * delivered).sum(1)
        self.status = torch.where(picked, dest_here, torch.where(delivered, EMPTY, self.status))
        self.taxi_wait = torch.where(picked, age_here, torch.where(delivered, 0, self.taxi_wait))
        self.station_dest = torch.where(taken, NO_PASSENGER, self.station_dest)
        self.station_age = torch.where(taken, 0, self.station_age)
        self.taxi_loc = self._moves[self.taxi_loc, action]

        self._arrive(u)
        self.picked_up, self.delivered = picked, delivered
        self.last_action = action.clone()

        b, dev = self.batch_size, self.device
        never = torch.zeros(b, dtype=torch.bool, device=dev)  # continuing
        every = torch.ones_like(acting)  # discrete time: every taxi acts at every step
        return reward, torch.ones(b, device=dev), never, every

    def _arrive(self, u: torch.Tensor) -> None:
        """The step's arrivals (``u [B, 3]``: the grid's draws; per station, fresh ones)."""
        if self.arrivals == "grid":
            arrive = u[:, 0] < self.arrival_prob
            station = (u[:, 1] * N_STATIONS).long().clamp_max(N_STATIONS - 1)
            slot = one_hot_mask(station, N_STATIONS) & arrive[:, None]  # [B, 4]
            other = (u[:, 2] * (N_STATIONS - 1)).long().clamp_max(N_STATIONS - 2)[:, None]
        else:  # every station its own Bernoulli process (draws: 4 arrivals, 4 destinations)
            v = self.rng.uniform(2 * N_STATIONS)
            slot = v[:, :N_STATIONS] < self.arrival_prob
            other = (v[:, N_STATIONS:] * (N_STATIONS - 1)).long().clamp_max(N_STATIONS - 2)
        stations = torch.arange(N_STATIONS, device=self.device)
        occupied = self.station_dest != NO_PASSENGER
        new = slot & ~occupied
        self.station_dest = torch.where(new, other + (other >= stations), self.station_dest)
        self.station_age = torch.where(new, 0, self.station_age)
        self.n_arrived = slot.sum(1)
        self.n_lost = (slot & occupied).sum(1)

    def _stations(self) -> torch.Tensor:
        """``stations`` index ``[B]`` (``sum_s code_s * 4**s``)."""
        powers = N_STATION_CODES ** torch.arange(N_STATIONS, device=self.device)
        return (station_code(self.station_dest) * powers).sum(1)

    def _observe(self) -> dict[str, torch.Tensor]:
        codes = station_code(self.station_dest)
        stations = self._stations()
        taxis = self.taxi_loc * N_STATUS + self.status
        powers = (N_LOCATIONS * N_STATUS) ** torch.arange(
            self.n_agents - 1, -1, -1, device=self.device
        )
        return {
            "observation": (taxis * powers).sum(1) * N_STATIONS_STATES + stations,
            "stations": stations,
            **{f"waiting_{name}": codes[:, s] for s, name in enumerate(STATION_NAMES)},
            "n_arrived": self.n_arrived.clone(),
            "n_lost": self.n_lost.clone(),
            "n_picked_up": self.picked_up.sum(1),
            "n_delivered": self.delivered.sum(1),
            "wait_delivered": self.wait_delivered.clone(),
            "n_waiting": (self.station_dest != NO_PASSENGER).sum(1),
        }

    def _observe_agents(self) -> dict[str, torch.Tensor]:
        taxis = self.taxi_loc * N_STATUS + self.status
        return {
            "taxi_loc": self.taxi_loc.clone(),
            "taxi_row": self.taxi_loc // 5,
            "taxi_col": self.taxi_loc % 5,
            "status": self.status.clone(),
            "own_state": taxis * N_STATIONS_STATES + self._stations()[:, None],
            "picked_up": self.picked_up.long(),
            "delivered": self.delivered.long(),
            "last_action": self.last_action.clone(),
        }
