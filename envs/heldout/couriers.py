"""Two couriers, three parcels in a corridor: a small cooperative task with an exact optimum.

A corridor of ``LENGTH`` cells holds parcels at ``PARCELS`` (cells 0, 4, 8). Two couriers
start in independent uniformly random cells; every step each moves ``Left`` or ``Right`` or
tries to ``Pick`` a parcel in its cell. The episode ends when every parcel is picked, and the
team pays -1 per step: the return is minus the makespan. Coordination pays: the couriers must
split the parcels by where both stand (one takes the near end, the other the middle and the
far end), and two couriers that each run the best one-courier plan ignore each other.

``exact_model`` is the joint MDP (``LENGTH**2 * 8`` states, 9 joint actions, deterministic);
``optimal_values`` solves it by value iteration (the reference), ``independent_values``
evaluates two couriers that each follow the optimal one-courier policy (no coordination).
"""

from __future__ import annotations

import torch

from hrl_torch.env.multiagent_env import MultiAgentBatchedEnv

LENGTH = 9
PARCELS = (0, 4, 8)
LEFT, RIGHT, PICK = 0, 1, 2
N_MASKS = 1 << len(PARCELS)
ALL = N_MASKS - 1
MAX_STEPS = 40


class CouriersEnv(MultiAgentBatchedEnv):
    """``pos [B, 2]`` of the couriers, ``parcels [B]`` still waiting (bit k: parcel k)."""

    state_keys = ("pos", "parcels")
    observation_sizes = {"parcels": N_MASKS}
    agent_observation_sizes = {"pos": LENGTH, "other": LENGTH}

    def __init__(self, seeds, envs_per_learner, max_episode_steps=MAX_STEPS, device="cpu"):
        super().__init__(seeds, envs_per_learner, 2, 3, max_episode_steps, device)
        self.pos = torch.zeros(self.batch_size, 2, dtype=torch.long, device=self.device)
        self.parcels = torch.full((self.batch_size,), ALL, dtype=torch.long, device=self.device)

    def _reset_rows(self, mask):
        start = torch.stack([self.rng.integers(LENGTH) for _ in range(2)], 1)
        self.pos = torch.where(mask[:, None], start, self.pos)
        self.parcels = self.parcels.masked_fill(mask, ALL)

    def _step_all(self, action, acting):
        self.pos, self.parcels = step(self.pos, self.parcels, action)
        reward = torch.full((self.batch_size,), -1.0, device=self.device)
        return reward, torch.ones_like(reward), self.parcels == 0, torch.ones_like(acting)

    def _observe(self):
        return {"parcels": self.parcels.clone()}

    def _observe_agents(self):
        return {"pos": self.pos.clone(), "other": self.pos.flip(1)}


def step(pos: torch.Tensor, parcels: torch.Tensor, action: torch.Tensor):
    """Both couriers' moves ``action [N, 2]`` from ``pos [N, 2]``, ``parcels [N]``."""
    move = torch.where(action == RIGHT, 1, torch.where(action == LEFT, -1, 0))
    pos = (pos + move).clamp(0, LENGTH - 1)
    for k, cell in enumerate(PARCELS):  # a courier picking at a parcel's cell takes it
        picked = ((action == PICK) & (pos == cell)).any(1)
        parcels = torch.where(picked, parcels & ~(1 << k), parcels)
    return pos, parcels


def encode(pos: torch.Tensor, parcels: torch.Tensor) -> torch.Tensor:
    """Joint state ``(pos0 * LENGTH + pos1) * N_MASKS + parcels``."""
    return (pos[..., 0] * LENGTH + pos[..., 1]) * N_MASKS + parcels


def exact_model():
    """``next_state [S, 9]`` (joint action ``a0 * 3 + a1``), ``terminal [S]``, ``starts [S]``.

    Every step costs 1; ``starts`` is the start distribution (uniform cells, every parcel).
    """
    s = torch.arange(LENGTH * LENGTH * N_MASKS)
    pos = torch.stack([s // N_MASKS // LENGTH, s // N_MASKS % LENGTH], 1)
    parcels = s % N_MASKS
    nxt = torch.stack(
        [
            encode(*step(pos, parcels, torch.tensor([a // 3, a % 3]).expand(len(s), 2)))
            for a in range(9)
        ],
        1,
    )
    starts = torch.zeros(len(s), dtype=torch.float64)
    starts[parcels == ALL] = 1.0 / LENGTH**2
    return nxt, parcels == 0, starts


def optimal_values(tol: float = 1e-9) -> torch.Tensor:
    """The optimal team return of every joint state (value iteration; 0 when done)."""
    nxt, terminal, _ = exact_model()
    v = torch.zeros(len(terminal), dtype=torch.float64)
    for _ in range(10 * MAX_STEPS):
        new = torch.where(terminal, 0.0, -1.0 + v[nxt].amax(1))
        if float((new - v).abs().max()) < tol:
            return new
        v = new
    raise RuntimeError("value iteration did not converge")


def one_courier_policy() -> torch.Tensor:
    """The optimal action of a courier alone ``[LENGTH * N_MASKS]`` (state ``pos * 8 + mask``).

    Ties go to the lowest action (Left, Right, Pick).
    """
    s = torch.arange(LENGTH * N_MASKS)
    pos, parcels = s // N_MASKS, s % N_MASKS
    nxt = []
    for a in range(3):
        p, m = step(torch.stack([pos, pos], 1), parcels, torch.tensor([a, a]).expand(len(s), 2))
        nxt.append(p[:, 0] * N_MASKS + m)
    nxt = torch.stack(nxt, 1)
    v = torch.zeros(len(s), dtype=torch.float64)
    for _ in range(10 * MAX_STEPS):
        v = torch.where(parcels == 0, 0.0, -1.0 + v[nxt].amax(1))
    q = v[nxt]
    return (q == q.amax(1, keepdim=True)).float().argmax(1)


def independent_values(limit: int = MAX_STEPS) -> torch.Tensor:
    """The team return of every joint state when each courier runs ``one_courier_policy``.

    Episodes cut at ``limit`` steps count ``-limit`` (none is cut: the plan always progresses).
    """
    nxt, terminal, _ = exact_model()
    policy = one_courier_policy()
    s = torch.arange(len(terminal))
    pos = torch.stack([s // N_MASKS // LENGTH, s // N_MASKS % LENGTH], 1)
    own = pos * N_MASKS + (s % N_MASKS)[:, None]
    joint = policy[own[:, 0]] * 3 + policy[own[:, 1]]
    follow = nxt[s, joint]
    v = torch.zeros(len(s), dtype=torch.float64)
    for _ in range(limit):
        v = torch.where(terminal, 0.0, -1.0 + v[follow])
    return v


def hierarchy_values(tol: float = 1e-9) -> torch.Tensor:
    """The best team return of Root -> Fetch0..2 with root choices that see the joint state.

    Per joint state with both couriers choosing ``[S]``.

    Below the root ``Fetch(k)`` walks the shortest way to parcel ``k`` and picks it; it ends
    when the parcel is gone. The root choices form an MDP over (joint state, both running
    tasks): a courier whose task ended chooses a waiting parcel, both at once when both
    choose. Equal to ``optimal_values`` on the starts where the hierarchy loses nothing.
    """
    nxt, terminal, _ = exact_model()
    n, k = len(terminal), len(PARCELS)
    z = torch.arange(n * (k + 1) ** 2)
    s, t0, t1 = z // (k + 1) ** 2, z // (k + 1) % (k + 1), z % (k + 1)
    pos = torch.stack([s // N_MASKS // LENGTH, s // N_MASKS % LENGTH], 1)
    parcels = s % N_MASKS
    cells = torch.tensor(PARCELS)
    options = []
    for c0 in range(k):
        for c1 in range(k):
            task = torch.stack(
                [torch.where(t0 == 0, c0 + 1, t0), torch.where(t1 == 0, c1 + 1, t1)], 1
            )
            ok = ((parcels[:, None] >> (task - 1)) & 1 == 1).all(1)
            cell = cells[task - 1]
            act = torch.where(pos == cell, PICK, torch.where(pos < cell, RIGHT, LEFT))
            p2, m2 = step(pos, parcels, act)
            left = torch.where((m2[:, None] >> (task - 1)) & 1 == 1, task, 0)
            z2 = encode(p2, m2) * (k + 1) ** 2 + left[:, 0] * (k + 1) + left[:, 1]
            options.append((z2, ok))
    v = torch.zeros(len(z), dtype=torch.float64)
    done = parcels == 0
    for _ in range(10 * MAX_STEPS):
        q = torch.stack([torch.where(ok, -1.0 + v[z2], -torch.inf) for z2, ok in options], 1)
        new = torch.where(done, 0.0, q.amax(1).clamp_min(-10.0 * MAX_STEPS))  # (unreachable)
        if float((new - v).abs().max()) < tol:
            return new[(t0 == 0) & (t1 == 0)]
        v = new
    raise RuntimeError("value iteration did not converge")
