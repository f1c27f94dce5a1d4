"""Robots collecting trash (Figures 3.1 and 6.1) as a torch-batched multi-agent env.

## Description
An office of two rooms, a corridor and a dump room (Figure 3.1 draws rooms and corridors; the
text gives no dimensions). Trash can T1 stands in the west room, T2 in the east room and the
Dump in the south room::

          0   1   2   3
        +---+---+---+---+
      0 | 1   . | .   2 |        T1 = (0, 0), T2 = (0, 3)
        +   +---+---+   +
      1 | .   .   .   . |        corridor
        +---+---+   +---+
      2 | .   .   D   . |        Dump = (2, 2)
        +---+---+---+---+

12 cells. T1 is 4 moves from the Dump, T2 only 3, and the cans are 5 moves apart, so which
robot serves which can matters (the coordination of Figure 6.1). ``n_agents`` robots (default
2) share the office; they never block each other (any number may stand on one cell).

Trash: each can holds at most one load (full or empty). A can that is empty at the start of a
step is refilled at its end with probability ``refill_prob`` (default 0.1), independently per
can; a can emptied during a step stays empty at least until the end of the next one. Each robot
carries at most one load.

## Action Space
``Discrete(7)`` per robot: 0 south, 1 north, 2 east, 3 west, 4 pick, 5 put, 6 wait. The moves
are grid moves instead of the text's *find wall* / *align with wall* / *follow wall*; a move
into a wall leaves the robot in place. ``pick`` by an empty robot at a full can takes its load
(when several empty robots pick at the same full can in one step, the lowest-index robot gets
it and the others' picks do nothing); ``put`` by a loaded robot at the Dump dumps its load.
Elsewhere pick and put do nothing. ``wait`` (idle) does nothing: it is the action of an agent
that has finished and waits for the others (the tau_all scheme of Section 6.1) or that has
nothing to collect.

## Observation
A TensorDict ``[B]`` (``hrl_torch.env.multiagent_env``). Shared fields: ``observation`` (the joint
state index, ``encode``: ``(24**n)`` robot codes times 4 can codes, 2,304 values for two
robots), ``cans`` (bit ``k`` set when can ``T(k+1)`` is full, 4 values), ``t1_full`` and
``t2_full`` (0/1), and the undeclared per-step metric ``n_dumped`` (loads dumped at this step).
Per robot (``"agents"`` ``[B, n]``): ``location`` (12, row-major), ``row`` (3), ``col`` (4),
``carrying`` (0/1), ``own_state`` (``(location * 2 + carrying) * 4 + cans``, 96 values: what
one robot sees), ``dumped`` (1 when this robot's put emptied it at this step) and
``last_action`` (0-6, 7 after a reset).

## Rewards
A team reward: +20 per load put in the Dump, -1 per robot for every action other than wait.

## Starting State
Both cans full, every robot empty on an independent uniformly random cell.

## Episode End
None: the task is continuing (never terminated; no time limit unless one is asked for). The
exact model (``exact_model``) serves average-reward, discounted and finite-horizon dynamic
programming alike, since the time is not part of the state.

## Exact model
``step_joint`` is the one step function of the env and of the model: given the robots, the
cans, the joint action and the random outcome (which cans *would* refill if empty, drawn the
same way in every state) it returns the next state and the reward. ``exact_model`` runs it
over every joint state, joint action and outcome: ``next_state [S, A, K]`` with the outcome
probabilities ``prob [K]`` (the same in every state) and ``reward [S, A]`` (the reward does not
depend on the outcome), like gymnasium's ``Taxi.P`` but batched (``TrashEnv.exact_model`` for
an env's own settings). ``TrashModel.chain`` turns a deterministic joint policy into a Markov
chain for ``hrl_torch.analysis.markov_chain_gain``; the dense ``[S, A, S]`` tables of
``hrl_torch.analysis.FiniteModel`` would take 2 GB for two robots (2,304 states x 49 joint
actions), 0.5 MB for one.

## Version History
* v0: layout, rewards and refill process reconstructed from Figures 3.1 and 6.1 (the text
  gives neither dimensions nor rewards).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import torch

from hrl_torch.common.devices import constant_on
from hrl_torch.common.ops import one_hot_mask
from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv

MAP = (
    "+---+---+---+---+",
    "| 1   . | .   2 |",
    "+   +---+---+   +",
    "| .   .   .   . |",
    "+---+---+   +---+",
    "| .   .   D   . |",
    "+---+---+---+---+",
)
N_ROWS, N_COLS = 3, 4
N_CELLS = N_ROWS * N_COLS
N_CANS = 2
N_CAN_CODES = 2**N_CANS
#: states of one robot: ``location * 2 + carrying``
N_ROBOT_CODES = N_CELLS * 2
N_OWN_STATES = N_ROBOT_CODES * N_CAN_CODES
N_ACTIONS = 7
SOUTH, NORTH, EAST, WEST, PICK, PUT, WAIT = range(N_ACTIONS)
NO_ACTION = N_ACTIONS  # ``last_action`` after a reset
DUMP_REWARD = 20.0
ACTION_COST = 1.0
REFILL_PROB = 0.1
#: guard on ``exact_model``: state x joint-action x outcome rows it may build
MAX_MODEL_ROWS = 20_000_000
_DELTA = {SOUTH: N_COLS, NORTH: -N_COLS, EAST: 1, WEST: -1}


def _parse_map() -> tuple[torch.Tensor, dict[str, int]]:
    """``moves [N_CELLS, N_ACTIONS]`` (next cell; non-moves stay) and the marked cells."""
    moves = torch.arange(N_CELLS).repeat(N_ACTIONS, 1).T.contiguous()
    marks = {}
    for r in range(N_ROWS):
        y, line = 1 + 2 * r, MAP[1 + 2 * r]
        for c in range(N_COLS):
            x, cell = 2 + 4 * c, r * N_COLS + c
            if line[x] != ".":
                marks[line[x]] = cell
            opening = {
                SOUTH: MAP[y + 1][x],
                NORTH: MAP[y - 1][x],
                EAST: line[x + 2],
                WEST: line[x - 2],
            }
            for action, char in opening.items():
                if char == " ":
                    moves[cell, action] = cell + _DELTA[action]
    return moves, marks


MOVES, _MARKS = _parse_map()
CANS = (_MARKS["1"], _MARKS["2"])  # cells of T1, T2
DUMP = _MARKS["D"]
#: can index at every cell (``N_CANS`` where there is none)
CAN_AT = torch.full((N_CELLS,), N_CANS, dtype=torch.long)
CAN_AT[list(CANS)] = torch.arange(N_CANS)


def n_joint_states(n_agents: int) -> int:
    """Number of joint states: ``24**n_agents * 4``."""
    return N_ROBOT_CODES**n_agents * N_CAN_CODES


def n_joint_actions(n_agents: int) -> int:
    """Number of joint actions: ``7**n_agents``."""
    return N_ACTIONS**n_agents


def _digits(index: torch.Tensor, base: int, n: int) -> torch.Tensor:
    """Mixed-radix digits ``[..., n]`` of ``index``, most significant first."""
    powers = base ** torch.arange(n - 1, -1, -1, device=index.device)
    return (index[..., None] // powers) % base


def _number(digits: torch.Tensor, base: int) -> torch.Tensor:
    """Inverse of ``_digits``: ``[..., n]`` digits to ``[...]`` indices."""
    n = digits.shape[-1]
    powers = base ** torch.arange(n - 1, -1, -1, device=digits.device)
    return (digits * powers).sum(-1)


def encode(location: torch.Tensor, carrying: torch.Tensor, cans: torch.Tensor) -> torch.Tensor:
    """Joint state index of robots ``[..., n]`` and cans ``[..., 2]`` (bool): shape ``[...]``.

    Robot ``j``'s code ``location * 2 + carrying`` is digit ``j`` (most significant first) in
    base 24; the can code ``t1_full + 2 * t2_full`` is the last digit (base 4).
    """
    robots = _number(location.long() * 2 + carrying.long(), N_ROBOT_CODES)
    return robots * N_CAN_CODES + can_code(cans)


def can_code(cans: torch.Tensor) -> torch.Tensor:
    """``[..., 2]`` bool to ``[...]`` in 0-3 (bit ``k``: can ``T(k+1)`` full)."""
    return (cans.long() << torch.arange(N_CANS, device=cans.device)).sum(-1)


def decode(state: torch.Tensor, n_agents: int) -> dict[str, torch.Tensor]:
    """Inverse of ``encode``: ``location`` / ``carrying`` ``[..., n]``, ``cans`` ``[..., 2]``."""
    state = state.long()
    robots = _digits(state // N_CAN_CODES, N_ROBOT_CODES, n_agents)
    bits = torch.arange(N_CANS, device=state.device)
    return {
        "location": robots // 2,
        "carrying": (robots % 2).bool(),
        "cans": ((state % N_CAN_CODES)[..., None] >> bits) % 2 == 1,
    }


class JointStep(NamedTuple):
    """What ``step_joint`` returns (shapes as its arguments)."""

    location: torch.Tensor
    carrying: torch.Tensor
    cans: torch.Tensor
    reward: torch.Tensor
    dumped: torch.Tensor


def step_joint(
    location: torch.Tensor,
    carrying: torch.Tensor,
    cans: torch.Tensor,
    action: torch.Tensor,
    refill: torch.Tensor,
) -> JointStep:
    """One step of every row, given its random outcome (the env's and the model's dynamics).

    Args:
        location: ``[B, n]`` long, the robots' cells.
        carrying: ``[B, n]`` bool.
        cans: ``[B, 2]`` bool, can full.
        action: ``[B, n]`` long in ``[0, 7)``.
        refill: ``[B, 2]`` bool, the outcome: can ``k`` refills at the end of the step if it
            was empty at its start.

    Returns:
        ``JointStep``: the next ``location``, ``carrying``, ``cans``, the team ``reward [B]``
        (float) and ``dumped [B, n]`` (bool: the robot put a load in the Dump).
    """
    device = location.device
    can_here = constant_on(CAN_AT, device)[location]  # [B, n], N_CANS where no can
    full_here = torch.cat([cans, torch.zeros_like(cans[:, :1])], 1).gather(1, can_here)
    tries = (action == PICK) & ~carrying & full_here
    claims = one_hot_mask(can_here, N_CANS + 1)[..., :N_CANS] & tries[..., None]  # [B, n, K]
    wins = claims & (claims.long().cumsum(1) == 1)  # the lowest-index robot at each can
    picked, emptied = wins.any(2), wins.any(1)
    dumped = (action == PUT) & carrying & (location == DUMP)
    reward = DUMP_REWARD * dumped.sum(1) - ACTION_COST * (action != WAIT).sum(1)
    return JointStep(
        location=constant_on(MOVES, device)[location, action],
        carrying=(carrying | picked) & ~dumped,
        cans=(cans & ~emptied) | (~cans & refill),
        reward=reward.float(),
        dumped=dumped,
    )


def refill_outcomes(refill_prob: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``K = 4`` random outcomes ``[K, 2]`` (bool) and their probabilities ``[K]`` (float64).

    Outcome ``k`` has bit ``c`` set when can ``c`` would refill; the env draws it with one
    uniform per can, ``u_c < refill_prob``, in every state.
    """
    outcomes = (torch.arange(N_CAN_CODES)[:, None] >> torch.arange(N_CANS)) % 2 == 1
    p = torch.tensor(float(refill_prob), dtype=torch.float64)
    prob = torch.where(outcomes, p, 1 - p).prod(1)
    return outcomes, prob


@dataclass(frozen=True)
class TrashModel:
    """The exact joint model of ``TrashEnv`` (see ``exact_model``).

    Joint action ``a`` has robot ``j``'s action as digit ``j`` in base 7, most significant
    first (``joint_action``).

    Attributes:
        n_agents: robots.
        next_state: ``[S, A, K]`` long, the state after joint action ``a`` under outcome ``k``.
        prob: ``[K]`` float64, outcome probabilities (the same in every state).
        reward: ``[S, A]`` float64, the team reward (independent of the outcome).
        dumped: ``[S, A]`` long, loads dumped by the step.
    """

    n_agents: int
    next_state: torch.Tensor
    prob: torch.Tensor
    reward: torch.Tensor
    dumped: torch.Tensor

    @property
    def n_states(self) -> int:
        """``S``."""
        return self.next_state.shape[0]

    @property
    def n_actions(self) -> int:
        """``A``, the number of joint actions."""
        return self.next_state.shape[1]

    def joint_action(self, action: torch.Tensor) -> torch.Tensor:
        """Joint action index of per-robot actions ``[..., n]``."""
        return _number(action.long(), N_ACTIONS)

    def robot_actions(self, joint: torch.Tensor) -> torch.Tensor:
        """Per-robot actions ``[..., n]`` of joint action indices."""
        return _digits(joint.long(), N_ACTIONS, self.n_agents)

    def probability(
        self, state: torch.Tensor, joint: torch.Tensor, next_state: torch.Tensor
    ) -> torch.Tensor:
        """``P(next_state | state, joint)`` for transitions given as three ``[M]`` tensors."""
        hits = self.next_state[state, joint] == next_state[:, None]
        return (hits * self.prob).sum(1)

    def start_distribution(self) -> torch.Tensor:
        """``[S]`` float64: the env's start distribution (cans full, robots empty, uniform)."""
        n = self.n_agents
        cells = _digits(torch.arange(N_CELLS**n), N_CELLS, n)
        full = torch.ones(len(cells), N_CANS, dtype=torch.bool)
        starts = encode(cells, torch.zeros_like(cells, dtype=torch.bool), full)
        dist = torch.zeros(self.n_states, dtype=torch.float64)
        dist[starts] = 1.0 / len(cells)
        return dist

    def chain(self, policy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The Markov chain of a deterministic joint policy ``[S]`` (joint action per state).

        Returns ``(P [S, S], r [S])`` in float64, e.g. for
        ``hrl_torch.analysis.markov_chain_gain``.
        """
        s = torch.arange(self.n_states)
        nxt = self.next_state[s, policy]  # [S, K]
        p = torch.zeros(self.n_states, self.n_states, dtype=torch.float64)
        p.index_put_((s[:, None].expand_as(nxt), nxt), self.prob.expand_as(nxt), accumulate=True)
        return p, self.reward[s, policy]


def exact_model(n_agents: int = 2, refill_prob: float = REFILL_PROB) -> TrashModel:
    """The exact joint model over every state, joint action and refill outcome.

    Built with ``step_joint`` itself, in one batch of ``S * A * K`` rows (451,584 for two
    robots; a ``ValueError`` above ``MAX_MODEL_ROWS``).
    """
    n_s, n_a = n_joint_states(n_agents), n_joint_actions(n_agents)
    outcomes, prob = refill_outcomes(refill_prob)
    k = len(prob)
    if n_s * n_a * k > MAX_MODEL_ROWS:
        raise ValueError(
            f"exact_model with {n_agents} robots needs {n_s * n_a * k:,} rows "
            f"(limit {MAX_MODEL_ROWS:,})"
        )
    grid = torch.meshgrid(torch.arange(n_s), torch.arange(n_a), torch.arange(k), indexing="ij")
    s, a, o = (t.reshape(-1) for t in grid)
    state = decode(s, n_agents)
    out = step_joint(
        state["location"],
        state["carrying"],
        state["cans"],
        _digits(a, N_ACTIONS, n_agents),
        outcomes[o],
    )
    next_state = encode(out.location, out.carrying, out.cans).view(n_s, n_a, k)
    reward = out.reward.view(n_s, n_a, k)[:, :, 0].double()
    dumped = out.dumped.sum(1).view(n_s, n_a, k)[:, :, 0]
    return TrashModel(n_agents, next_state, prob, reward, dumped)


class TrashEnv(MultiAgentBatchedEnv):
    """Torch-batched trash collection by ``n_agents`` robots (see the module docstring).

    Discrete time: every robot acts at every step.

    Args:
        seeds: one seed per learner.
        envs_per_learner: envs per learner ``E``; the batch is ``len(seeds) * E``.
        n_agents: robots per env row.
        refill_prob: probability that an empty can is refilled at the end of a step.
        max_episode_steps: optional time limit; the task itself is continuing (default none).
        device: where the state lives.
        own_rewards: each robot learns from its own dumps and costs (their sum is the team
            reward), not from the team reward: with a shared reward a robot's values carry
            the other robots' +20s as noise (hrl_torch.env.multiagent_env).
    """

    state_keys = ("location", "carrying", "cans", "dumped", "last_action")
    agent_observation_sizes = {
        "location": N_CELLS,
        "row": N_ROWS,
        "col": N_COLS,
        "carrying": 2,
        "own_state": N_OWN_STATES,
        "dumped": 2,
        "last_action": N_ACTIONS + 1,
    }

    def __init__(
        self,
        seeds: Sequence[int] = (0,),
        envs_per_learner: int = 1,
        n_agents: int = 2,
        refill_prob: float = REFILL_PROB,
        max_episode_steps: int | None = None,
        device: torch.device | str = "cpu",
        own_rewards: bool = False,
    ) -> None:
        super().__init__(seeds, envs_per_learner, n_agents, N_ACTIONS, max_episode_steps, device)
        self.own_rewards = own_rewards
        if not 0.0 <= refill_prob <= 1.0:
            raise ValueError(f"refill_prob must be in [0, 1], got {refill_prob}")
        self.refill_prob = float(refill_prob)
        self.observation_sizes = {
            "observation": n_joint_states(self.n_agents),
            "cans": N_CAN_CODES,
            "t1_full": 2,
            "t2_full": 2,
        }
        shape, dev = (self.batch_size, self.n_agents), self.device
        self.location = torch.zeros(shape, dtype=torch.long, device=dev)
        self.carrying = torch.zeros(shape, dtype=torch.bool, device=dev)
        self.cans = torch.ones(self.batch_size, N_CANS, dtype=torch.bool, device=dev)
        self.dumped = torch.zeros(shape, dtype=torch.bool, device=dev)
        self.last_action = torch.full(shape, NO_ACTION, dtype=torch.long, device=dev)

    def exact_model(self) -> TrashModel:
        """The exact joint model for this env's number of robots and refill probability."""
        return exact_model(self.n_agents, self.refill_prob)

    def _reset_rows(self, mask: torch.Tensor) -> None:
        start = self.rng.integers(N_CELLS, extra=self.n_agents)  # drawn for every row
        m2 = mask[:, None]
        self.location = torch.where(m2, start, self.location)
        self.carrying = self.carrying & ~m2
        self.cans = self.cans | m2
        self.dumped = self.dumped & ~m2
        self.last_action = torch.where(m2, NO_ACTION, self.last_action)

    def _step_all(self, action: torch.Tensor, acting: torch.Tensor):  # type: ignore[override]
        refill = self.rng.uniform(N_CANS) < self.refill_prob  # [B, 2], drawn for every row
        out = step_joint(self.location, self.carrying, self.cans, action, refill)
        self.location, self.carrying, self.cans = out.location, out.carrying, out.cans
        self.dumped = out.dumped
        self.last_action = action.clone()
        b, dev = self.batch_size, self.device
        never = torch.zeros(b, dtype=torch.bool, device=dev)  # continuing
        every = torch.ones_like(acting)  # discrete time: every robot acts at every step
        reward = out.reward
        if self.own_rewards:  # each robot's own dumps and costs; their sum is the team's
            reward = DUMP_REWARD * out.dumped.float() - ACTION_COST * (action != WAIT).float()
        return reward, torch.ones(b, device=dev), never, every

    def _observe(self) -> dict[str, torch.Tensor]:
        cans = can_code(self.cans)
        return {
            "observation": encode(self.location, self.carrying, self.cans),
            "cans": cans,
            "t1_full": self.cans[:, 0].long(),
            "t2_full": self.cans[:, 1].long(),
            "n_dumped": self.dumped.sum(1),
        }

    def _observe_agents(self) -> dict[str, torch.Tensor]:
        robot = self.location * 2 + self.carrying.long()
        return {
            "location": self.location.clone(),
            "row": self.location // N_COLS,
            "col": self.location % N_COLS,
            "carrying": self.carrying.long(),
            "own_state": robot * N_CAN_CODES + can_code(self.cans)[:, None],
            "dumped": self.dumped.long(),
            "last_action": self.last_action.clone(),
        }
