"""The best gain of the trash hierarchy (Figure 6.1) when every root choice sees the joint state.

The reference for Cooperative HRL on trash (``scripts/trash_exact.py``). Below the root every
subtask runs its best policy, which needs no choice: ``CollectTk`` goes the shortest way to
``Tk`` and picks while the robot is empty (``Tk`` is then full: an empty robot at an empty can
has ended the subtask), and the shortest way to the Dump and puts while it carries; robots
never block each other, so no other lower policy does better. What is left to choose is each
robot's root child (``CollectT1``, ``CollectT2``, ``Wait``) whenever its previous one ended
(tau_continue; ``Wait`` is a one-step primitive). That choice made with the whole joint state
and the other robots' tasks is an MDP over (env state, each robot's running task):
``hierarchy_model`` builds it, ``hierarchical_optimum`` solves it. Its gain bounds every policy
the hierarchy expresses with a cooperative root (which sees only the robot's own state and the
others' tasks) from above, and is bounded by the flat joint MDP's.
"""

from __future__ import annotations

import torch

from envs.trash import CANS, DUMP, MOVES, N_CELLS, PICK, PUT, WAIT, decode, exact_model
from hrl_torch.analysis.joint import optimal_gain

#: a robot's task: 0 none (it chooses now), 1 CollectT1, 2 CollectT2 (3 = Wait, chosen only)
N_TASKS = 3


def distances(target: int) -> torch.Tensor:
    """Shortest move count from every cell to ``target`` ``[N_CELLS]``."""
    d = torch.full((N_CELLS,), N_CELLS)
    d[target] = 0
    for _ in range(N_CELLS):
        d = torch.minimum(d, d[MOVES[:, :4]].min(1).values + 1)
    return d


def lower_action(location, carrying, choice) -> torch.Tensor:
    """The primitive of each robot's task below the root (``choice`` 1, 2 Collect, 3 Wait)."""
    step = {c: distances(c)[MOVES[:, :4]].argmin(1) for c in (*CANS, DUMP)}  # [N_CELLS]
    can = torch.tensor(CANS)[(choice - 1).clamp(0, 1)]
    to_can = torch.where(can == CANS[0], step[CANS[0]][location], step[CANS[1]][location])
    fetch = torch.where(location == can, PICK, to_can)
    bring = torch.where(location == DUMP, PUT, step[DUMP][location])
    return torch.where(choice == 3, WAIT, torch.where(carrying, bring, fetch))


def hierarchy_model(n_agents: int = 2, refill_prob: float = 0.1):
    """The root-choice MDP: ``(next [Z, C, K], prob [K], reward [Z, C], env_state [Z])``.

    State ``z = s * 3**n + sum_j task_j 3**(n-1-j)`` (task 0: robot ``j`` chooses at ``z``);
    choice ``c``: every robot's root child, digit ``j`` of ``c`` in base 3 (0 CollectT1, 1
    CollectT2, 2 Wait). A robot with a running task must keep it and a robot may start
    ``CollectTk`` only when ``Tk`` is full: other choices have reward ``-inf``.
    """
    m = exact_model(n_agents, refill_prob)
    tasks = N_TASKS**n_agents
    z = torch.arange(m.n_states * tasks)
    s, code = z // tasks, z % tasks
    task = task_digits(code, n_agents)  # [Z, n]
    state = decode(s, n_agents)
    n_choices = 3**n_agents
    nxt = torch.zeros(len(z), n_choices, len(m.prob), dtype=torch.long)
    reward = torch.full((len(z), n_choices), -torch.inf, dtype=torch.float64)
    for c in range(n_choices):
        choice = task_digits(torch.full_like(s, c), n_agents) + 1  # [Z, n] in 1..3
        full = state["cans"].gather(1, (choice - 1).clamp(0, 1))
        allowed = ((task == 0) & ((choice == 3) | full)) | (task == choice)
        a = m.joint_action(lower_action(state["location"], state["carrying"], choice))
        s2 = m.next_state[s, a]  # [Z, K]
        after = decode(s2, n_agents)
        can_full = after["cans"].gather(2, (choice - 1).clamp(0, 1)[:, None].expand(-1, 4, -1))
        ended = (choice == 3)[:, None] | (~after["carrying"] & ~can_full)
        left = torch.where(ended, 0, choice[:, None])  # [Z, K, n]
        nxt[:, c] = s2 * tasks + _number(left)
        reward[:, c] = torch.where(allowed.all(1), m.reward[s, a], -torch.inf)
    return nxt, m.prob, reward, s


def hierarchical_optimum(n_agents: int = 2, refill_prob: float = 0.1) -> float:
    """The best gain of the trash hierarchy with root choices that see the joint state."""
    nxt, prob, reward, _ = hierarchy_model(n_agents, refill_prob)
    return optimal_gain(nxt, prob, reward)


def optimal_policy(nxt, prob, reward, tol: float = 1e-10, max_iter: int = 100_000):
    """A gain-optimal choice per state of ``hierarchy_model`` (relative value iteration)."""
    h = torch.zeros(nxt.shape[0], dtype=torch.float64)
    for _ in range(max_iter):
        q = reward + (h[nxt] * prob).sum(-1)
        t = 0.5 * (h + q.amax(1))
        new = t - t[0]
        if float((new - h).abs().max()) < tol:
            return q.argmax(1)
        h = new
    raise RuntimeError(f"relative value iteration did not converge in {max_iter} iterations")


def projected_gain(refill_prob: float = 0.1, selfish: bool = False) -> tuple[float, float]:
    """``(gain of the joint-state optimum, gain of its projection on the cooperative root)``.

    ``selfish``: project on what a selfish root sees instead (its cell and the cans only).

    Two robots. The projection chooses, for each robot and what its cooperative root sees (its
    cell and the cans when it chooses, and the other robot's task as sequential broadcast
    shows it: robot 0 the other's running task or none, robot 1 also robot 0's fresh choice),
    the choice the optimum makes most often there in its stationary distribution. It is a
    policy the cooperative root can express, so its exact gain bounds the best such policy
    from below (the joint-state optimum bounds it from above).
    """
    nxt, prob, reward, s = hierarchy_model(2, refill_prob)
    z = torch.arange(len(s))
    best = optimal_policy(nxt, prob, reward)
    start = choosing_start(s, refill_prob)
    gain, weight = gain_and_occupancy(nxt[z, best], prob, reward[z, best], start)
    task = task_digits(z % 9, 2)
    state = decode(s, 2)
    cans = state["cans"][:, 0].long() + 2 * state["cans"][:, 1].long()
    own = state["location"] * 4 + cans[:, None]  # [Z, 2] (an empty robot chooses)
    digit = torch.stack([best // 3, best % 3], 1)
    tell = 0 if selfish else 1  # (a selfish root sees no task: code 0 for all)
    seen = torch.stack(
        [own[:, 0] * 4 + tell * task[:, 1], own[:, 1] * 4 + tell * fresh_task(task, digit[:, 0])], 1
    )
    rule = []
    for j in range(2):
        votes = torch.zeros(N_CELLS * 16, 3, dtype=torch.float64)
        chooses = task[:, j] == 0
        votes.index_put_((seen[chooses, j], digit[chooses, j]), weight[chooses] + 1e-12, True)
        rule.append(votes.argmax(1))
    c0 = torch.where(task[:, 0] == 0, rule[0][seen[:, 0]], task[:, 0] - 1)
    c1 = rule[1][own[:, 1] * 4 + tell * fresh_task(task, c0)]
    c1 = torch.where(task[:, 1] == 0, c1, task[:, 1] - 1)
    choice = c0 * 3 + c1
    wait = torch.isinf(reward[z, choice])  # a can the rule wants is empty here: wait instead
    choice = torch.where(wait & (task[:, 0] == 0), 6 + c1, choice)
    choice = torch.where(torch.isinf(reward[z, choice]), choice - choice % 3 + 2, choice)
    projected, _ = gain_and_occupancy(nxt[z, choice], prob, reward[z, choice], start)
    return gain, projected


def fresh_task(task: torch.Tensor, c0: torch.Tensor) -> torch.Tensor:
    """Robot 0's task as robot 1 sees it: running (1, 2), or just chosen (1, 2, 3 = Wait)."""
    return torch.where(task[:, 0] == 0, c0 + 1, task[:, 0])


def choosing_start(s: torch.Tensor, refill_prob: float) -> torch.Tensor:
    """Both robots choose at the env's start states."""
    start = torch.zeros(len(s), dtype=torch.float64)
    first = exact_model(2, refill_prob).start_distribution()
    start[first.nonzero().squeeze(1) * 9] = first[first > 0]
    return start


def gain_and_occupancy(nxt, prob, reward, start, iters: int = 200_000, tol: float = 1e-13):
    """Gain and long-run state occupancy of a chain ``nxt [Z, K]`` from ``start``."""
    src = torch.arange(len(start)).repeat_interleave(len(prob))
    dst, w = nxt.reshape(-1), prob.repeat(len(start))
    d = start.clone()
    for _ in range(iters):
        new = 0.5 * (d + torch.zeros_like(d).index_add_(0, dst, d[src] * w))
        if float((new - d).abs().sum()) < tol:
            return float(new @ reward), new
        d = new
    raise RuntimeError("the chain's distribution did not settle")


def task_digits(x: torch.Tensor, n: int) -> torch.Tensor:
    """The base-3 task digits of ``x`` ``[N, n]`` (robot 0 first)."""
    powers = N_TASKS ** torch.arange(n - 1, -1, -1)
    return (x[:, None] // powers) % N_TASKS


def _number(d: torch.Tensor) -> torch.Tensor:
    n = d.shape[-1]
    return (d * N_TASKS ** torch.arange(n - 1, -1, -1)).sum(-1)


__all__ = [
    "choosing_start",
    "distances",
    "fresh_task",
    "gain_and_occupancy",
    "hierarchical_optimum",
    "hierarchy_model",
    "lower_action",
    "optimal_policy",
    "projected_gain",
    "task_digits",
]
