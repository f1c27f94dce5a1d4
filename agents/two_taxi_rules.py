"""Hand-written dispatching rules for the two-taxi-earlier domain.

How large a gap coordination allows.

Each rule acts like a taxi of the learners' hierarchy (Figure 6.10): an empty taxi without a
task chooses a station with a waiting passenger (its ``Get``), drives there on a shortest path
and picks up; a loaded taxi drives to the destination and puts down; with nothing to serve it
waits. The rules differ in how a free taxi picks its station and when its ``Get`` ends:

- ``race``: the nearest waiting passenger, whatever the other taxi does; the task ends only at
  the station (the text's rule: the loser of a race drives on and returns empty);
- ``race-taken``: the same choice, but the task ends as soon as the station is empty (the
  first build's ``Get``, ``two-taxi-earlier``);
- ``coordinated``: a waiting passenger that no other taxi is already driving to (one
  ``Tell`` per choice, as Cooperative HRL's free communication); taxis choosing at the same
  step are matched closest (taxi, station) pair first;
- ``coordinated-unseen``: the same, but taxis choosing at the same step do not see each
  other's choice (each takes its nearest station among those not already claimed).

``race`` is what a selfish taxi can do at best without knowing the other's task;
``coordinated`` what knowing it buys with the simplest rule. Their difference measures the
room the task leaves for Cooperative HRL (``scripts/two_taxi_rules.py``).
"""

from __future__ import annotations

import torch

from envs.two_taxi import (
    EMPTY,
    MOVES,
    N_LOCATIONS,
    NO_PASSENGER,
    PICKUP,
    PUTDOWN,
    STATION_LOC,
    WAIT,
    TwoTaxiEnv,
)

RULES = ("race", "race-taken", "coordinated")
#: beyond the rules table: coordinated choices that do not see choices of the same step
RULES_EXTRA = ("coordinated-unseen",)
NONE = -1  # no task


def _shortest_paths() -> tuple[torch.Tensor, torch.Tensor]:
    """``(dist [25, 25], first [25, 25])``: shortest paths on the taxi map.

    ``dist``: moves between locations; ``first``: for every ``(loc, goal)`` the first move of
    a shortest path (``WAIT`` at the goal).
    """
    moves = MOVES[:, :4]  # [25, 4] the four moves
    dist = torch.full((N_LOCATIONS, N_LOCATIONS), 10**6, dtype=torch.long)
    dist.fill_diagonal_(0)
    for _ in range(N_LOCATIONS):  # Bellman: d(l, g) = min_a d(move(l, a), g) + 1
        dist = torch.minimum(dist, dist[moves].min(1).values + 1)
    after = dist[moves]  # [25, 4, 25]: distance after each move
    first = (after == (dist - 1)[:, None, :]).long().argmax(1)  # the first such move
    first.fill_diagonal_(WAIT)
    return dist, first


DIST, FIRST = _shortest_paths()


class RulePolicy:
    """One dispatching rule for every taxi of every row of a ``TwoTaxiEnv``.

    Args:
        env: the env it drives (its state is read directly).
        rule: one of ``RULES``.
    """

    def __init__(self, env: TwoTaxiEnv, rule: str) -> None:
        if rule not in RULES + RULES_EXTRA:
            raise ValueError(f"rule must be one of {RULES + RULES_EXTRA}, got {rule!r}")
        self.env, self.rule = env, rule
        self.task = torch.full((env.batch_size, env.n_agents), NONE, dtype=torch.long)
        self._dist_to_station = DIST[:, STATION_LOC]  # [25, 4]

    def act(self) -> torch.Tensor:
        """The actions ``[B, n]`` of the current state (ended tasks replaced first)."""
        env = self.env
        waiting = env.station_dest != NO_PASSENGER  # [B, 4]
        loc, loaded = env.taxi_loc, env.status != EMPTY  # [B, n]
        task = self.task
        has_task = task != NONE
        task_waiting = waiting.gather(1, task.clamp_min(0))
        at_task = has_task & (loc == STATION_LOC[task.clamp_min(0)])
        ended = loaded | (at_task & ~task_waiting)  # picked up, or arrived to nobody
        if self.rule == "race-taken":
            ended = ended | ~task_waiting
        task = torch.where(has_task & ended, NONE, task)
        choosing = ~loaded & (task == NONE)
        dist = self._dist_to_station[loc]  # [B, n, 4]
        if self.rule == "coordinated":
            choice = self._match(dist, waiting, task, choosing)
        else:  # every taxi its nearest waiting passenger (not claimed, if coordinated-unseen)
            allowed = waiting[:, None, :].expand_as(dist)
            if self.rule == "coordinated-unseen":
                allowed = allowed & ~self._claimed(task)[:, None, :]
            dist = torch.where(allowed, dist, 10**6)
            choice = torch.where(allowed.any(2), dist.argmin(2), NONE)
        self.task = task = torch.where(choosing, choice, task)
        goal = torch.where(loaded, STATION_LOC[env.status.clamp_max(3)], STATION_LOC[task])
        act = torch.where(loc == goal, torch.where(loaded, PUTDOWN, PICKUP), FIRST[loc, goal])
        return torch.where(~loaded & (task == NONE), WAIT, act)

    @staticmethod
    def _claimed(task: torch.Tensor) -> torch.Tensor:
        """``[B, 4]``: stations some taxi is driving to."""
        claimed = torch.zeros(task.shape[0], 4, dtype=torch.bool)
        for i in range(task.shape[1]):
            has = task[:, i] != NONE
            claimed[has, task[has, i]] = True
        return claimed

    @staticmethod
    def _match(dist, waiting, task, choosing) -> torch.Tensor:
        """Stations ``[B, n]`` for the choosing taxis (``NONE`` for the others).

        No station another taxi drives to; the closest (taxi, station) pair first (ties: the
        lower index), one station per taxi.
        """
        b, n, s = dist.shape
        free = waiting & ~RulePolicy._claimed(task)
        choice = torch.full((b, n), NONE, dtype=torch.long)
        open_ = choosing.clone()
        for _ in range(n):
            d = torch.where(open_[:, :, None] & free[:, None, :], dist, 10**6).view(b, n * s)
            best = d.argmin(1)
            ok = d.gather(1, best[:, None])[:, 0] < 10**6
            taxi, station = best // s, best % s
            rows = ok.nonzero()[:, 0]
            choice[rows, taxi[rows]] = station[rows]
            open_[rows, taxi[rows]] = False
            free[rows, station[rows]] = False
        return choice


def measure(
    rule: str,
    seeds=(0, 1, 2, 3, 4),
    rows: int = 4,
    steps: int = 20_000,
    burn_in: int = 500,
    **env_options,
) -> dict[str, list[float]]:
    """Throughput (per 5,000 steps) and average wait per seed of ``rule`` on a ``TwoTaxiEnv``.

    ``env_options``: ``TwoTaxiEnv`` keywords (``mean_interarrival``, ``arrivals``,
    ``n_agents``). Each seed's numbers pool its ``rows`` rows over ``steps`` steps after
    ``burn_in``.
    """
    env = TwoTaxiEnv(list(seeds), rows, **env_options)
    policy = RulePolicy(env, rule)
    env.reset()
    delivered = torch.zeros(env.batch_size, dtype=torch.long)
    waited = torch.zeros(env.batch_size, dtype=torch.long)
    arrived = torch.zeros(env.batch_size, dtype=torch.long)
    for t in range(burn_in + steps):
        td = env.step(policy.act())
        if t >= burn_in:
            delivered += td["n_delivered"]
            waited += td["wait_delivered"]
            arrived += td["n_arrived"]
    per_seed = lambda x: x.view(len(seeds), rows).sum(1).double()  # noqa: E731
    d, w, a = per_seed(delivered), per_seed(waited), per_seed(arrived)
    return {
        "throughput": (d * 5_000 / (steps * rows)).tolist(),
        "wait": (w / d).tolist(),
        "arrivals": (a * 5_000 / (steps * rows)).tolist(),
    }
