"""Line 16 of Algorithm 3 over the eligibility rings of ``HPGRLLearner`` (``pg.py``).

Static shapes: every (row, depth) pair's ring is read every step and the pairs not selected
(or the ring entries past a pair's count) weigh 0, so a step reads nothing back to the host
(docs/design.md, "Any device"). Each parameter still receives its nonzero terms in the order
the compacted rows gave them (ring-entry order), so the sums are the same.
"""

from __future__ import annotations

import torch


def trace_weights(learner, rows, pairs: torch.Tensor, cell: torch.Tensor) -> torch.Tensor:
    """``w [B * S, K + 1]`` (float64) of every ring entry; 0 outside ``pairs``' filled entries.

    Online, after step ``k``: ``w_n = r_k beta^(k - n)`` (line 16 with ``z_{k+1}``).
    At the renewal: ``w_n = sum_{k >= n} beta^(k - n) r_k - b``, the (discounted)
    reward-to-go of Equation 5.2 less the baseline of the pair's (learner, group) ``cell``.
    """
    cfg = learner.config
    k1, beta = cfg.trace_len + 1, cfg.beta
    count = rows["count"].view(-1)
    slot = torch.arange(k1, device=count.device)
    filled = (slot < count[:, None]) & pairs.view(-1, 1)
    reward = rows["reward"].view(-1, k1).double() * filled
    if cfg.online:
        last = reward.gather(1, (count - 1).clamp_min(0)[:, None])
        weight = last * beta ** (count[:, None] - 1 - slot).clamp_min(0).double()
    elif beta == 1.0:
        weight = reward.flip(1).cumsum(1).flip(1)
    else:
        scale = beta ** slot.double()
        weight = (reward * scale).flip(1).cumsum(1).flip(1) / scale
    if cfg.baseline:
        weight = weight - baseline(learner, cell.reshape(-1), weight, filled)
    return torch.where(filled, weight, 0.0)


def apply_traces(learner, rows, pairs: torch.Tensor, alpha, cell: torch.Tensor) -> None:
    """``theta += alpha * sum_n w_n g_n`` over the ring entries of the pairs ``pairs [B, S]``.

    Frozen: the same sum (without ``alpha``) into ``grad_sum``.
    """
    w = trace_weights(learner, rows, pairs, cell).float()
    # (an entry past its pair's count may hold any index: clamped, it adds 0 in range)
    index = rows["index"].view(-1).clamp(0, learner.sentinel)
    value = rows["value"].view(*w.shape, -1)
    frozen = learner.config.frozen
    scaled = (w if frozen else alpha * w)[..., None]
    step = torch.where(scaled != 0, scaled * value, 0.0)  # (a stale ring entry adds 0)
    target = learner.grad_sum if frozen else learner.theta
    target.index_add_(0, index, step.view(-1))
    target[-1] = 0.0


def baseline(learner, cell: torch.Tensor, togo: torch.Tensor, filled: torch.Tensor):
    """``b`` of each pair's ``cell`` ``[n, 1]``; then ``b += rate (mean R_n - b)``.

    The mean is over the filled entries of the pairs that end now (others add 0).
    """
    b = learner.reward_to_go_mean.view(-1)
    used = b[cell][:, None].double()
    sums = torch.zeros_like(b, dtype=torch.float64).index_add_(0, cell, (togo * filled).sum(1))
    counts = torch.zeros_like(sums).index_add_(0, cell, filled.sum(1).double())
    seen = counts > 0
    mean = (sums / counts.clamp_min(1)).float()
    b.add_(torch.where(seen, learner.config.baseline * (mean - b), 0.0))
    return used
