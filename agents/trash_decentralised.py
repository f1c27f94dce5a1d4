"""A tighter lower bound on the best cooperative-root policy of trash (issue 33, Must show).

``agents/trash_optimum.py`` brackets the best policy the cooperative root can express (each
robot's root choice sees its own cell and the cans, and the other robot's task as sequential
broadcast shows it) between 1.486 (the joint-state optimum projected on that view) and 1.527
(the joint-state optimum). Here the projected rules are improved by decentralised policy
improvement: with the current joint policy's occupancy ``d`` and relative values ``h``, the
first-order change of the gain from setting robot ``j``'s rule to ``a`` at its view ``e`` is
``sum_z d(z) (Q(z, c_a(z)) - Q(z, c(z)))`` over the states ``z`` where robot ``j`` chooses
and sees ``e`` (the policy-difference lemma); every improving entry of one robot changes at
once if that raises the exact gain, else the first of the ``top`` best entries that does
alone. Every policy met is expressed by the cooperative root and its gain is exact, so the
best gain found is a lower bound for the best cooperative-root policy.
"""

from __future__ import annotations

import torch

from agents.trash_optimum import (
    choosing_start,
    fresh_task,
    hierarchy_model,
    optimal_policy,
    projected_gain,
    task_digits,
)
from envs.trash import N_CELLS, decode

_VIEWS = N_CELLS * 16  # a robot's view: its cell x the cans (N_CELLS * 4) x the other's task code


class _Views:
    """What each robot's cooperative root sees at every state of ``hierarchy_model``."""

    def __init__(self, s: torch.Tensor, reward: torch.Tensor) -> None:
        z = torch.arange(len(s))
        self.task = task_digits(z % 9, 2)
        state = decode(s, 2)
        cans = state["cans"][:, 0].long() + 2 * state["cans"][:, 1].long()
        self.own = state["location"] * 4 + cans[:, None]
        self.reward, self.z = reward, z

    def choice(self, rule0: torch.Tensor, rule1: torch.Tensor) -> torch.Tensor:
        """The joint choice ``[Z]`` of the robots' rules (as ``projected_gain`` builds it)."""
        task, own, z = self.task, self.own, self.z
        c0 = torch.where(task[:, 0] == 0, rule0[own[:, 0] * 4 + task[:, 1]], task[:, 0] - 1)
        c1 = rule1[own[:, 1] * 4 + fresh_task(task, c0)]
        c1 = torch.where(task[:, 1] == 0, c1, task[:, 1] - 1)
        choice = c0 * 3 + c1
        wait = torch.isinf(self.reward[z, choice])  # a can the rule wants is empty: wait
        choice = torch.where(wait & (task[:, 0] == 0), 6 + c1, choice)
        return torch.where(torch.isinf(self.reward[z, choice]), choice - choice % 3 + 2, choice)

    def seen(self, j: int, rule0: torch.Tensor) -> torch.Tensor:
        """Robot ``j``'s view index ``[Z]`` (robot 1 sees robot 0's fresh choice)."""
        if j == 0:
            return self.own[:, 0] * 4 + self.task[:, 1]
        c0 = torch.where(
            self.task[:, 0] == 0, rule0[self.own[:, 0] * 4 + self.task[:, 1]], self.task[:, 0] - 1
        )
        return self.own[:, 1] * 4 + fresh_task(self.task, c0)


def chain(nxt, prob, reward, start, d=None, h=None, tol: float = 1e-12, iters: int = 400_000):
    """Gain, occupancy from ``start`` and relative values of the chain ``nxt [Z, K]``.

    Lazy power iteration for the occupancy, lazy relative value iteration for ``h`` (warm
    starts ``d``, ``h``).
    """
    src, dst = torch.arange(len(start)).repeat_interleave(len(prob)), nxt.reshape(-1)
    w = prob.repeat(len(start))
    d = start.clone() if d is None else d
    for _ in range(iters):
        new = 0.5 * (d + torch.zeros_like(d).index_add_(0, dst, d[src] * w))
        if float((new - d).abs().sum()) < tol:
            break
        d = new
    gain = float(new @ reward)
    h = torch.zeros_like(start) if h is None else h
    for _ in range(iters):
        t = 0.5 * (h + reward - gain + (h[nxt] * prob).sum(-1))
        t = t - t[0]
        if float((t - h).abs().max()) < 1e-10:
            break
        h = t
    return gain, new, t


def improved_lower_bound(refill_prob: float = 0.1, rounds: int = 30, top: int = 20, log=print):
    """``(projected gain, best gain found, (rule0, rule1))`` of cooperative-root policies."""
    nxt, prob, reward, s = hierarchy_model(2, refill_prob)
    views = _Views(s, reward)
    rules = _projected_rules(nxt, prob, reward, s, views, refill_prob)
    start = choosing_start(s, refill_prob)
    z = views.z
    choice = views.choice(*rules)
    gain, d, h = chain(nxt[z, choice], prob, reward[z, choice], start)
    first = gain
    log(f"projected rules: gain {gain:.5f}")
    for step in range(rounds):
        improved = False
        for j in (0, 1):
            q = reward + (h[nxt] * prob).sum(-1)  # [Z, C]
            chooses = views.task[:, j] == 0
            seen = views.seen(j, rules[0])
            delta = torch.zeros(_VIEWS, 3, dtype=torch.float64)
            now = q[z, choice]
            for a in range(3):
                trial = [r.clone() for r in rules]
                trial[j] = torch.full_like(rules[j], a)
                c = views.choice(*trial)
                gainz = torch.where(chooses, d * (q[z, c] - now), 0.0)
                delta[:, a].index_add_(0, seen, torch.nan_to_num(gainz, neginf=-1e9))
            best = delta.argmax(1)
            better = delta.gather(1, best[:, None]).squeeze(1) > 1e-12
            if not bool(better.any()):
                continue
            order = delta.amax(1).argsort(descending=True)[: int(better.sum())][:top]
            for candidate in ["all", *order.tolist()]:
                new_rules = [r.clone() for r in rules]
                if candidate == "all":
                    new_rules[j] = torch.where(better, best, rules[j])
                else:
                    new_rules[j][candidate] = best[candidate]
                c = views.choice(*new_rules)
                g, d2, h2 = chain(nxt[z, c], prob, reward[z, c], start, d, h)
                if g > gain + 1e-9:
                    rules, choice, gain, d, h, improved = new_rules, c, g, d2, h2, True
                    log(f"round {step} robot {j} (entry {candidate}): gain {gain:.5f}")
                    break
        if not improved:
            break
    return first, gain, rules


def _projected_rules(nxt, prob, reward, s, views: _Views, refill_prob: float):
    """``projected_gain``'s rules: the joint optimum's most frequent choice per view."""
    from agents.trash_optimum import gain_and_occupancy

    z = views.z
    best = optimal_policy(nxt, prob, reward)
    _, weight = gain_and_occupancy(
        nxt[z, best], prob, reward[z, best], choosing_start(s, refill_prob)
    )
    digit = torch.stack([best // 3, best % 3], 1)
    seen = torch.stack(
        [
            views.own[:, 0] * 4 + views.task[:, 1],
            views.own[:, 1] * 4 + fresh_task(views.task, digit[:, 0]),
        ],
        1,
    )
    rules = []
    for j in range(2):
        votes = torch.zeros(_VIEWS, 3, dtype=torch.float64)
        chooses = views.task[:, j] == 0
        votes.index_put_((seen[chooses, j], digit[chooses, j]), weight[chooses] + 1e-12, True)
        rules.append(votes.argmax(1))
    return rules


__all__ = ["chain", "improved_lower_bound", "projected_gain"]
