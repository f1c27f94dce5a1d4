"""A straightforward plain-Python MAXQ-Q on taxi: the reference the batched trainer is timed by.

Dietterich (2000), Table 4, without pseudo rewards (taxi has none, so the internal and external
completions coincide and one ``C`` table per subtask suffices), with the hierarchy, state
abstractions and hyperparameters of ``agents/taxi.py``:

- ``Root -> {Get, Put}``, ``Get -> {Navigate(t), Pickup}``, ``Put -> {Navigate(t), Putdown}``,
  ``Navigate(t) -> {North, South, East, West}``; ``Navigate(t)`` is one subtask per station,
  shared by Get and Put (recursively optimal: one table per subtask), with ``t`` bound to the
  passenger's station under Get and to the destination under Put;
- abstractions: Root (passenger, destination), Get and Pickup (taxi, passenger), Put and Putdown
  (taxi, destination), Navigate(t) (taxi), the four moves none (one value each);
- a child whose termination predicate already holds is not available to its parent;
- ``V(i, s)`` of a terminated subtask is 0; a terminal ``s'`` (the subtask's own termination or
  the episode's end) gives the completion target 0;
- the 200-step time limit is a cut, not a termination: the parent of a child that was cut gets
  no update, and a child that ended on its own at the cut still bootstraps from ``s'``.

Everything is plain Python: a recursive ``maxq(node, state)``, list-of-list tables, the
``random`` module. The env is gymnasium's ``Taxi-v4`` transition table (``env.unwrapped.P``)
stepped in plain Python with the time limit re-implemented (``TableTaxi``); ``GymTaxi`` steps
``gymnasium.make("Taxi-v4")`` itself instead (slower: its wrappers cost more per step than the
learning does).
"""

from __future__ import annotations

import random
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import gymnasium

# ---------------------------------------------------------------------- the env
MAX_EPISODE_STEPS = 200
STATION_LOC = (0, 4, 20, 23)  # taxi_loc = row * 5 + col of R(0,0), G(0,4), Y(4,0), B(4,3)
IN_TAXI = 4


class TableTaxi:
    """Gymnasium's ``Taxi-v4`` dynamics as plain lists, with the 200-step time limit."""

    def __init__(self) -> None:
        base = gymnasium.make("Taxi-v4").unwrapped
        self.next_state = [[base.P[s][a][0][1] for a in range(6)] for s in range(500)]
        self.reward = [[float(base.P[s][a][0][2]) for a in range(6)] for s in range(500)]
        self.terminal = [[bool(base.P[s][a][0][3]) for a in range(6)] for s in range(500)]
        self.starts = [s for s in range(500) if base.initial_state_distrib[s] > 0]
        self.s = 0
        self.t = 0

    def reset(self, start: int) -> int:
        """Start an episode in state ``start``."""
        self.s, self.t = start, 0
        return start

    def step(self, a: int) -> tuple[int, float, bool, bool]:
        """Return ``(next state, reward, terminated, truncated)``."""
        s = self.s
        self.s = self.next_state[s][a]
        self.t += 1
        terminated = self.terminal[s][a]
        return self.s, self.reward[s][a], terminated, not terminated and self.t >= MAX_EPISODE_STEPS


class GymTaxi:
    """``gymnasium.make("Taxi-v4")`` (TimeLimit 200 included) behind ``TableTaxi``'s interface."""

    def __init__(self) -> None:
        self.env = gymnasium.make("Taxi-v4")
        self.starts = TableTaxi().starts
        self.env.reset(seed=0)

    def reset(self, start: int) -> int:
        """Start an episode in state ``start`` (gymnasium draws one; we overwrite it)."""
        self.env.reset()
        self.env.unwrapped.s = start
        return start

    def step(self, a: int) -> tuple[int, float, bool, bool]:
        """Return ``(next state, reward, terminated, truncated)``."""
        s, r, terminated, truncated, _ = self.env.step(a)
        return int(s), float(r), terminated, truncated


# ---------------------------------------------------------------------- the hierarchy
SOUTH, NORTH, EAST, WEST, PICKUP, PUTDOWN = range(6)  # primitives are the env actions
ROOT, GET, PUT = 6, 7, 8
NAV = (9, 10, 11, 12)  # Navigate(R), Navigate(G), Navigate(Y), Navigate(B)
N_NODES = 13
CHILDREN = {
    ROOT: (GET, PUT),
    GET: (*NAV, PICKUP),
    PUT: (*NAV, PUTDOWN),
    **{n: (NORTH, SOUTH, EAST, WEST) for n in NAV},
}
NAMES = {ROOT: "Root", GET: "Get", PUT: "Put"}  # the node names of agents/taxi.py
NAMES.update({n: f"Navigate_{t}" for n, t in zip(NAV, "RGYB", strict=True)})
NAMES.update(zip(range(6), ("South", "North", "East", "West", "Pickup", "Putdown"), strict=True))
N_STATES = {ROOT: 20, GET: 125, PUT: 100, **{n: 25 for n in NAV}}
N_STATES.update({SOUTH: 1, NORTH: 1, EAST: 1, WEST: 1, PICKUP: 125, PUTDOWN: 100})


def abstract(node: int, s: int) -> int:
    """Dietterich's state abstraction of gymnasium state ``s`` for ``node``."""
    taxi, passenger, destination = s // 20, (s // 4) % 5, s % 4
    if node == ROOT:
        return passenger * 4 + destination
    if node in (GET, PICKUP):
        return taxi * 5 + passenger
    if node in (PUT, PUTDOWN):
        return taxi * 4 + destination
    if node in NAV:
        return taxi
    return 0  # North/South/East/West: leaf irrelevance


def terminated(node: int, s: int) -> bool:
    """Termination predicate of a subtask (Root ends only with the episode)."""
    if node == GET:
        return (s // 4) % 5 == IN_TAXI
    if node == PUT:
        return (s // 4) % 5 != IN_TAXI
    if node in NAV:
        return s // 20 == STATION_LOC[NAV.index(node)]
    return False


def available(node: int, s: int) -> list[int]:
    """Child slots of ``node`` allowed in ``s``: not yet terminated, Navigate(t) bound."""
    slots = []
    for k, child in enumerate(CHILDREN[node]):
        if child in NAV:
            bound = (s // 4) % 5 if node == GET else s % 4
            if NAV.index(child) != bound:
                continue
        if child >= ROOT and terminated(child, s):
            continue
        slots.append(k)
    return slots


# ---------------------------------------------------------------------- the learner
@dataclass
class Hyper:
    """MAXQ-Q hyperparameters; the epsilon schedule is linear over env steps.

    ``c_init`` / ``v_init`` are the initial completion and primitive values (the benchmark copies
    them, like everything else here, from the learner ``agents/taxi.py`` builds).
    """

    alpha: float = 0.5
    gamma: float = 1.0
    eps_start: float = 1.0
    eps_end: float = 0.05
    eps_steps: int = 20_000
    c_init: float = 0.0
    v_init: float = 0.0


class ThresholdReached(Exception):  # noqa: N818  (a signal, not an error)
    """Raised from inside the recursion when an evaluation reaches the threshold."""


class PlainMaxQ:
    """MAXQ-Q with list tables: ``C[node][state][slot]`` and ``V[primitive][state]``."""

    def __init__(self, seed: int, hyper: Hyper, env=None) -> None:
        self.h = hyper
        self.env = env or TableTaxi()
        self.rng = random.Random(seed)
        c0, v0 = hyper.c_init, hyper.v_init
        self.C = {i: [[c0] * len(CHILDREN[i]) for _ in range(N_STATES[i])] for i in CHILDREN}
        self.V = {a: [v0] * N_STATES[a] for a in range(6)}
        self.steps = 0  # env steps so far (the epsilon schedule reads it)
        self.episode_end = False  # the episode terminated
        self.cut = False  # the episode hit the time limit
        self.between_steps = None  # hook called whenever every update of the last step is done
        self.eval_env = TableTaxi()

    # -- values
    def value(self, i: int, s: int) -> float:
        """``V(i, s)``: learned for primitives, ``max_a V(a, s) + C(i, s, a)`` otherwise."""
        if i < ROOT:
            return self.V[i][abstract(i, s)]
        if terminated(i, s):
            return 0.0
        slots = available(i, s)
        if not slots:
            return 0.0
        row = self.C[i][abstract(i, s)]
        children = CHILDREN[i]
        return max(self.value(children[k], s) + row[k] for k in slots)

    def greedy(self, i: int, s: int, rng: random.Random) -> int:
        """Best available child slot of ``i`` in ``s``, random among ties."""
        row = self.C[i][abstract(i, s)]
        children = CHILDREN[i]
        best, ties = -float("inf"), []
        for k in available(i, s):
            q = self.value(children[k], s) + row[k]
            if q > best:
                best, ties = q, [k]
            elif q == best:
                ties.append(k)
        return ties[0] if len(ties) == 1 else rng.choice(ties)

    def epsilon(self) -> float:
        """Linear epsilon schedule over env steps."""
        h = self.h
        frac = min(self.steps / max(h.eps_steps, 1), 1.0)
        return h.eps_start + frac * (h.eps_end - h.eps_start)

    # -- learning (Dietterich's Table 4)
    def maxq(self, i: int, s: int) -> tuple[int, int, bool]:
        """Run subtask ``i`` from ``s``, learning; return ``(s', steps, ended on its own)``."""
        h = self.h
        if i < ROOT:  # primitive: execute, V(i, s) <- (1-alpha) V + alpha r
            s2, r, term, trunc = self.env.step(i)
            self.steps += 1
            self.episode_end, self.cut = term, trunc
            row, k = self.V[i], abstract(i, s)
            row[k] = (1 - h.alpha) * row[k] + h.alpha * r
            return s2, 1, True
        count = 0
        while True:  # i is not terminated in s (its parent checked)
            if self.between_steps is not None:  # (the periodic evaluation)
                self.between_steps(self)
            slots = available(i, s)
            if self.rng.random() < self.epsilon():
                k = self.rng.choice(slots)
            else:
                k = self.greedy(i, s, self.rng)
            s2, n, child_done = self.maxq(CHILDREN[i][k], s)
            count += n
            done = self.episode_end or terminated(i, s2)
            if child_done or done:  # a child cut by the time limit teaches its parent nothing
                target = 0.0 if done else h.gamma**n * self.value(i, s2)
                row = self.C[i][abstract(i, s)]
                row[k] = (1 - h.alpha) * row[k] + h.alpha * target
            if done:
                return s2, count, True
            if self.cut:
                return s2, count, False
            s = s2

    def run_episode(self) -> None:
        """One training episode from a random start state."""
        s = self.env.reset(self.rng.choice(self.env.starts))
        self.episode_end = self.cut = False
        self.maxq(ROOT, s)
        if self.between_steps is not None:
            self.between_steps(self)

    # -- greedy evaluation
    def play(self, i: int, s: int, ep: list, rng: random.Random) -> tuple[int, bool]:
        """Run subtask ``i`` greedily from ``s`` without learning; ``ep = [return, end, cut]``."""
        if i < ROOT:
            s2, r, term, trunc = self.eval_env.step(i)
            ep[0] += r
            ep[1], ep[2] = term, trunc
            return s2, True
        while True:
            s2, _ = self.play(CHILDREN[i][self.greedy(i, s, rng)], s, ep, rng)
            if ep[1] or terminated(i, s2):
                return s2, True
            if ep[2]:
                return s2, False
            s = s2

    def evaluate(self, starts: Sequence[int], seed: int = 0) -> float:
        """Mean return of the greedy policy over episodes from ``starts`` (200 steps at most).

        The tie-breaking stream restarts every time, so the result depends on the tables only.
        """
        rng = random.Random(seed)
        total = 0.0
        for start in starts:
            ep = [0.0, False, False]
            self.play(ROOT, self.eval_env.reset(start), ep, rng)
            total += ep[0]
        return total / len(starts)


# ---------------------------------------------------------------------- runs
@dataclass
class PlainRun:
    """Outcome of ``train_to_threshold`` for one seed (times in seconds)."""

    seed: int
    steps_to_threshold: int | None
    steps: int
    seconds: float
    cpu_seconds: float
    eval_seconds: float
    evaluations: int
    agent: PlainMaxQ = field(repr=False)

    @property
    def train_seconds(self) -> float:
        return self.seconds - self.eval_seconds

    def summary(self) -> dict:
        """The numbers, without the agent."""
        return {
            "seed": self.seed,
            "steps_to_threshold": self.steps_to_threshold,
            "steps": self.steps,
            "seconds": self.seconds,
            "cpu_seconds": self.cpu_seconds,
            "train_seconds": self.train_seconds,
            "eval_seconds": self.eval_seconds,
            "evaluations": self.evaluations,
        }


def train_to_threshold(
    seed: int,
    hyper: Hyper,
    eval_starts: Sequence[int],
    eval_every: int,
    threshold: float = 7.5,
    max_steps: int = 200_000,
) -> PlainRun:
    """Train until the greedy policy's mean return over ``eval_starts`` reaches ``threshold``.

    Evaluates every ``eval_every`` env steps (also in the middle of an episode, as the batched
    trainer does); ``steps_to_threshold`` is the env step count of the first evaluation at or
    above the threshold (``None`` if ``max_steps`` ran out first). The clock starts at the first
    training step: building the tables is set-up.
    """
    agent = PlainMaxQ(seed, hyper)
    clock = {"eval": 0.0, "n": 0, "next": eval_every, "hit": None}

    def check(a: PlainMaxQ) -> None:
        if a.steps >= clock["next"]:
            t0 = time.perf_counter()
            mean = a.evaluate(eval_starts)
            clock["eval"] += time.perf_counter() - t0
            clock["n"] += 1
            clock["next"] = a.steps + eval_every
            if mean >= threshold:
                clock["hit"] = a.steps
                raise ThresholdReached
        if a.steps >= max_steps:
            raise ThresholdReached

    agent.between_steps = check
    wall0, cpu0 = time.perf_counter(), time.process_time()
    try:
        while True:
            agent.run_episode()
    except ThresholdReached:
        pass
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    return PlainRun(seed, clock["hit"], agent.steps, wall, cpu, clock["eval"], clock["n"], agent)


def steps_per_second(seed: int, hyper: Hyper, seconds: float, env=None) -> float:
    """Training env steps per second of one learner from scratch (no evaluation)."""
    agent = PlainMaxQ(seed, hyper, env)
    start = time.perf_counter()

    def stop(a: PlainMaxQ) -> None:
        if a.steps % 1024 == 0 and time.perf_counter() - start >= seconds:
            raise ThresholdReached

    agent.between_steps = stop
    try:
        while True:
            agent.run_episode()
    except ThresholdReached:
        pass
    return agent.steps / (time.perf_counter() - start)
