"""Line 16 of Algorithm 3 over the eligibility rings of ``HPGRLLearner`` (``pg.py``).

Static shapes (off the CPU): every (row, depth) pair's ring is read every step and the pairs
not selected (or the ring entries past a pair's count) weigh 0, so a step reads nothing back
to the host (docs/design.md, "Any device"). Each parameter still receives its nonzero terms in
the order the compacted rows give them (ring-entry order), so the sums are the same as the
CPU's compacted path.
"""

from __future__ import annotations

import torch

from hrl_torch.common.devices import static_shapes
from hrl_torch.common.ops import lookup

#: ring entries (pairs x (trace length + 1)) above which an eager step off the CPU compacts
#: like the CPU's: the static pass reads every entry of every ring at every step, O(trace
#: length) per row, where a compaction costs two reads back to the host (benchmarks/RESULTS.md,
#: "GPU run of 2026-11-27"). A replayed step (``static_rows``) is static at any size.
STATIC_RING_ENTRIES = 1 << 20


def ring_entries(learner, rows: int) -> int:
    """Ring entries the static pass reads per step for ``rows`` batch rows."""
    return rows * len(learner.depths) * (learner.config.trace_len + 1)


def static_pass(learner, pairs: torch.Tensor) -> bool:
    """Whether ``apply_traces`` takes the static pass (``STATIC_RING_ENTRIES``)."""
    if learner.static_rows is not None:
        return learner.static_rows
    entries = pairs.numel() * (learner.config.trace_len + 1)
    return static_shapes(pairs.device) and entries <= STATIC_RING_ENTRIES


def entry_weights(learner, count, reward, filled, cell) -> torch.Tensor:
    """``w [n, K + 1]`` (float64) of the ring entries of ``n`` pairs (``reward``: their rings).

    Online, after step ``k``: ``w_n = r_k beta^(k - n)`` (line 16 with ``z_{k+1}``).
    At the renewal: ``w_n = sum_{k >= n} beta^(k - n) r_k - b``, the (discounted)
    reward-to-go of Equation 5.2 less the baseline of the pair's (learner, group) ``cell``.
    """
    cfg = learner.config
    beta = cfg.beta
    slot = torch.arange(reward.shape[1], device=count.device)
    reward = reward.double() * filled
    if cfg.online:
        last = reward.gather(1, (count - 1).clamp_min(0)[:, None])
        weight = last * beta ** (count[:, None] - 1 - slot).clamp_min(0).double()
    elif beta == 1.0:
        weight = reward.flip(1).cumsum(1).flip(1)
    else:
        scale = beta ** slot.double()
        weight = (reward * scale).flip(1).cumsum(1).flip(1) / scale
    if cfg.baseline:
        weight = weight - baseline(learner, cell, weight, filled)
    return weight


def apply_traces(learner, rows, pairs: torch.Tensor, alpha, cell: torch.Tensor) -> None:
    """``theta += alpha * sum_n w_n g_n`` over the ring entries of the pairs ``pairs [B, S]``.

    Frozen: the same sum (without ``alpha``) into ``grad_sum``. Off the CPU up to
    ``STATIC_RING_ENTRIES`` (or with ``learner.static_rows``) every ring is read, with static
    shapes; else only the selected pairs' filled entries (``nonzero``: a host read). Same sums.
    """
    if static_pass(learner, pairs):
        _apply_static(learner, rows, pairs, alpha, cell)
        return
    k1 = learner.config.trace_len + 1
    pair = pairs.view(-1).nonzero().squeeze(1)  # flat (row, depth) ids
    if pair.numel() == 0:
        return
    count = lookup(rows["count"].view(-1), pair)
    # the filled entries, pair by pair in ring order (what ``filled.nonzero()`` lists), in
    # O(entries): no [pairs, K + 1] mask
    owner = torch.repeat_interleave(torch.arange(pair.numel(), device=pair.device), count)
    start = torch.repeat_interleave(count.cumsum(0) - count, count)
    slot = torch.arange(owner.numel(), device=pair.device) - start
    entry = lookup(pair, owner) * k1 + slot  # flat ring-entry ids
    if learner.config.online:
        w = _online_weights(learner, rows, pair * k1 + (count - 1).clamp_min(0), count, owner, slot)
    else:
        filled = torch.arange(k1, device=pair.device) < count[:, None]
        reward = lookup(rows["reward"].view(-1, k1), pair)
        weight = entry_weights(learner, count, reward, filled, lookup(cell.view(-1), pair))
        w = weight[owner, slot].float()
    index = lookup(rows["index"].view(-1, learner.width), entry)
    value = lookup(rows["value"].view(-1, learner.width), entry)
    _add(learner, index.reshape(-1), (w if learner.config.frozen else alpha * w)[:, None] * value)


def _online_weights(learner, rows, last, count, owner, slot) -> torch.Tensor:
    """``entry_weights``' online ``w_n = r_k beta^(k - n)``, at the filled entries only.

    ``last``: each pair's newest ring entry (this step's reward). O(entries), not O(pairs x K).
    """
    r = lookup(rows["reward"].view(-1), last).double()
    beta = learner.config.beta
    if beta == 1.0:  # (beta ** m is exactly 1)
        return lookup(r, owner).float()
    age = (lookup(count, owner) - 1 - slot).double()
    return (lookup(r, owner) * beta**age).float()


def _apply_static(learner, rows, pairs: torch.Tensor, alpha, cell: torch.Tensor) -> None:
    """``apply_traces`` over every ring entry: 0 outside the selected pairs' filled ones."""
    k1 = learner.config.trace_len + 1
    count = rows["count"].view(-1)
    filled = (torch.arange(k1, device=count.device) < count[:, None]) & pairs.view(-1, 1)
    weight = entry_weights(learner, count, rows["reward"].view(-1, k1), filled, cell.reshape(-1))
    w = torch.where(filled, weight, 0.0).float()
    # (an entry past its pair's count holds a stale index in range, ``update`` clamps what it
    # writes, and a finite value: it adds 0)
    scaled = w if learner.config.frozen else alpha * w
    _add(learner, rows["index"].view(-1), scaled[..., None] * rows["value"].view(*w.shape, -1))


def _add(learner, index: torch.Tensor, step: torch.Tensor) -> None:
    target = learner.grad_sum if learner.config.frozen else learner.theta
    target.index_add_(0, index, step.reshape(-1))
    target[-1:].zero_()  # (the sentinel; no tensor from host data)


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


def check_overflow(learner, over: torch.Tensor, node: torch.Tensor) -> None:
    """Raise (or, deferred, latch) a (row, depth) whose ring is full ``over [B, S]``."""
    deferred = learner.deferred_overflow
    if deferred is not None and deferred.takes(over):  # (no read: ``deferred_checks``)
        deferred.record(over.any(1), over=over, node=node)
    elif bool(over.any()):
        row = int(over.any(1).nonzero()[0])
        raise overflow_error(learner, row, {"over": over, "node": node})


def overflow_error(learner, row: int, saved: dict) -> RuntimeError:
    """The error of a ring that overflowed in batch row ``row``."""
    depth = int(saved["over"][row].nonzero()[0])
    name = learner.graph.names[int(saved["node"][row, depth])]
    return RuntimeError(
        f"PG node {name!r} selected more than trace_len={learner.config.trace_len} children in "
        "one invocation; raise PGConfig.trace_len or bound the subtask with the executor's guard"
    )


def value_baseline_traces(learner, rows, pairs: torch.Tensor, alpha, cell) -> None:
    """Equation 5.2 less a state baseline: ``theta += alpha sum_n (R_n - V(s_n)) g_n``.

    At the renewal of the pairs ``pairs [B, S]``; ``R_n`` is the (``beta``-discounted)
    reward-to-go of ring entry ``n`` and ``V(s_n)`` the mean of ``learner.value_table`` over
    the entry's active tiles (the policy's own CMAC: ``g_n``'s indices). ``V`` depends on
    ``s_n`` alone and is read before this update changes it, so the estimate stays unbiased
    (``E[g_n | s_n] = 0``). Then ``V`` moves toward ``R_n`` (Monte Carlo): every active tile by
    ``value_rate`` times the mean of ``R_n - V(s_n)`` over the entries that hit it.

    ``learner`` holds ``value_table`` (laid out like ``theta``) and ``value_rate``
    (``PGConfig.value_rate``). A softmax head's entries are its state's row, so ``V`` is then
    a table over its abstract states. Used by ``HPGRLLearner.apply_traces`` and by the ship's
    ``-text`` low level (``agents/ship_text.py``), where it was first measured (issue 26).
    """
    k1, width = learner.config.trace_len + 1, learner.width
    if static_pass(learner, pairs):  # every pair, the others weigh 0 (no host read)
        pair, chosen = torch.arange(pairs.numel(), device=pairs.device), pairs.reshape(-1)
    else:
        pair = pairs.reshape(-1).nonzero().squeeze(1)
        if pair.numel() == 0:
            return
        chosen = torch.ones_like(pair, dtype=torch.bool)
    count = rows["count"].view(-1)[pair]
    filled = (torch.arange(k1, device=pair.device) < count[:, None]) & chosen[:, None]
    reward = rows["reward"].view(-1, k1)[pair]
    togo = entry_weights(learner, count, reward, filled, cell.view(-1)[pair])
    index = rows["index"].view(-1, k1, width)[pair]  # [n, K + 1, T] (stale entries in range)
    table = learner.value_table
    advantage = torch.where(filled, togo.float() - table[index].mean(-1), 0.0)
    flat = index.reshape(-1)
    hits = filled[..., None].expand_as(index).reshape(-1).float()
    total = torch.zeros_like(table).index_add_(
        0, flat, advantage[..., None].expand_as(index).reshape(-1)
    )
    seen = torch.zeros_like(table).index_add_(0, flat, hits)
    table.add_(learner.value_rate * total / seen.clamp_min(1.0))
    table[-1:].zero_()  # (the sentinel)
    step = (alpha * advantage)[..., None] * rows["value"].view(-1, k1, width)[pair]
    learner.theta.index_add_(0, flat, step.reshape(-1))
    learner.theta[-1:].zero_()
def head_blocks(learner) -> list[torch.Tensor]:
    """Copies ``[P, K]`` of the blocks of ``learner``'s self-stepping heads (``_stepped``)."""
    p = learner.n_learners
    return [learner.params.block(t).reshape(p, -1).clone() for t, _ in learner._stepped]


def step_heads(learner, before: list[torch.Tensor], alpha) -> None:
    """Line 16's step ``alpha F`` of each self-stepping head, replaced by its optimizer's.

    ``F`` (Equation 5.2's estimate, ``(theta - before) / alpha``) is the same; only how far it
    moves the head differs (``PolicyHead.optimizer_step``, e.g. Adam).
    """
    for (t, head), old in zip(learner._stepped, before, strict=False):  # (frozen: none)
        block = learner.params.block(t).view(learner.n_learners, -1)
        block.copy_(old + head.optimizer_step((block - old) / alpha))
