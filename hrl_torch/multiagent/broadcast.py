"""Sequential broadcast within a decision epoch (Cooperative HRL, Sections 6.3 and 6.5).

The text's rule: "as soon as an agent selects an action at a cooperative subtask, it broadcasts
it to the team", so "whenever an agent is about to choose an action at an l-th level
cooperative subtask, it knows the subtasks in U_l being performed by all its teammates". When
several agents of one env row choose at the same step (at a reset, or when their ``U_l``
subtasks end together), ``Cooperation.broadcast == "sequential"`` lets them choose in agent
order: agent ``j`` sees the fresh ``U_l`` choices of agents ``k < j`` and, for ``k > j``, what
they perform before choosing (their running ``U_l`` subtask, or none when theirs just ended).

How it is computed, on the batched rows: every agent chooses once with the others' codes after
this step's pops; then the rows that chose a new ``U_l`` subtask although the code they should
have seen differs are restored to their stacks before the choice and choose again, with the same
random numbers (a row's stream never depends on other rows), until no row changes (at most
``n - 1`` rounds: agent ``j``'s choice is final once agents ``0..j-1``'s are). A step without
simultaneous choices costs one evaluation, as before.

A code enters the context only through the cooperative subtasks' abstract states
(``CooperativeSubtask.abstract = base * K + code``), so a context with other codes is the
evaluated one with those columns moved by the codes' difference and the learner's values
evaluated again (``recoded``): the graph's predicates are not called again (the same numbers;
``RECODE = False`` computes the whole context, as before).
"""

from __future__ import annotations

import torch

from hrl_torch.execution.transitions import LEVEL, ChoosesAll, SelectsRows
from hrl_torch.learners.base import finished


class SameDraws:
    """``policy`` choosing with the random numbers already drawn at this step.

    It has the capabilities ``policy`` has (``same_draws`` picks the class): ``choose_all``
    answers ``None`` (choose level by level) where ``policy`` cannot choose all at once.
    """

    def __init__(self, policy) -> None:
        self.policy = policy

    def new_step(self) -> None:
        """Keep this step's draw (the choice is made again, not a new choice)."""

    def select(self, inst, ctx, available, step: int, push: int):
        """``policy``'s choice."""
        return self.policy.select(inst, ctx, available, step, push)

    def choose_all(self, ctx, step: int):
        """``policy``'s choices for every chooser, or ``None``."""
        return self.policy.choose_all(ctx, step) if isinstance(self.policy, ChoosesAll) else None


class SameDrawsRows(SameDraws):
    """``SameDraws`` of a policy that can choose for some rows only (``SelectsRows``)."""

    def select_rows(self, inst, ctx, available, step: int, push: int, rows):
        """``policy``'s choice for the rows ``rows``."""
        return self.policy.select_rows(inst, ctx, available, step, push, rows)


def same_draws(policy) -> SameDraws:
    """``policy`` choosing again with this step's draws, with the capabilities it has."""
    return SameDrawsRows(policy) if isinstance(policy, SelectsRows) else SameDraws(policy)


#: ``None``: stop the re-choosing rounds early on the CPU only; ``True``: never (every device,
#: no host read); ``False``: always (the fastest on a CPU, reads the device on a GPU)
STATIC_ROUNDS: bool | None = None
#: a context with other codes from the evaluated one (``recoded``); ``False``: computed anew
RECODE = True


def recoded(agent, ctx, rows):
    """The context of ``rows`` (``ctx``'s observations with other codes), with its values.

    Only the cooperative subtasks' abstract states depend on a code, by ``+ code``, so they
    move by the difference of the codes; every other field is ``ctx``'s. Where that does not
    hold (a tabulated graph, invocation memory, frozen values) the context is computed anew.
    """
    if not RECODE or ctx is None or ctx.table_row is not None or agent.graph.memory_nodes:
        return agent.context(rows)
    if agent.frozen is not None:
        return agent.context(rows)
    abstract = ctx.abstract
    for level, column in zip(agent.levels, agent.code_columns, strict=True):
        shift = rows[level.key] - ctx.obs[level.key]
        abstract = abstract + shift[:, None] * column
    new = type(ctx)(
        rows, ctx.learner, abstract, ctx.terminated, ctx.blocked, ctx.available, ctx.features
    )
    agent.learner.evaluate_checked(new)
    agent.ctx = new
    return new


def seen_codes(agent, level, post: torch.Tensor, final: torch.Tensor) -> torch.Tensor:
    """The others' ``U_l`` code each agent row sees when it chooses in agent order ``[B * n]``.

    ``post [B, n]``: every agent's ``U_l`` code after this step's pops (before choosing);
    ``final [B, n]``: after the choices. Agent ``j`` sees ``final`` of the agents before it
    and ``post`` of the agents after it, in radix ``level.radix`` (``MultiAgentAgent``).
    """
    n = agent.n_agents
    if n == 1:
        return torch.zeros_like(agent.executor.learner)
    order = agent.other_agents  # [n, n - 1]
    if final is post:  # (before any choice: every other agent's code after the pops)
        others = post[:, order]
    else:
        others = torch.where(agent.earlier_others, final[:, order], post[:, order])
    return (others * level.weights).sum(-1).view(-1)  # [B, n, n - 1] -> [B * n]


def choose_in_order(agent, rows, fixed: dict, ctx=None, batch=None) -> tuple[torch.Tensor, object]:
    """Push children for every agent row, agents of one env row choosing in index order.

    ``rows``: the step as agent rows (``MultiAgentAgent._rows``); ``fixed``: the levels whose
    codes are not broadcast (a communicating level's replies), by index, kept as in ``rows``;
    ``ctx``: the context of ``rows`` (evaluated or not), used as it is where no code changed;
    ``batch``: the step's transitions (``None``: none, nothing reads the targets' context).
    Returns the actions ``[B * n]`` and the context whose values the learning targets read
    (each row's codes as it saw them when choosing; ``targets_needed``).
    """
    ex, n = agent.executor, agent.n_agents
    acting, before = ex.acting, ex.stack.tensors()
    post = [agent.own_codes(level).view(-1, n) for level in agent.levels]
    agent.epoch_codes = post
    used = [_codes(agent, k, post[k], post[k], rows, fixed) for k in range(len(agent.levels))]
    # a round re-chooses, with the same draws, only the rows whose seen codes changed (in the
    # others it changes nothing); on the CPU rounds stop when none did (a cheap host read),
    # elsewhere all n - 1 run, so the step reads nothing back (a CUDA graph can replay it)
    cpu = ex.device.type == "cpu" and not ex.static_guard  # (a replayed step: static)
    stop_early = cpu if STATIC_ROUNDS is None else not STATIC_ROUNDS
    if ctx is None or not stop_early or _changed(agent, rows, used):
        ctx = recoded(agent, ctx, _with_codes(agent, rows, used))
    elif not ctx.values:  # (``rows``' codes are the ones seen: evaluate ``ctx`` itself)
        ctx = agent.evaluated(ctx)
    action = ex.act(ctx, agent.policy, agent.schedule_clock)
    invoked = ex.invoked
    for _ in range(n - 1):
        final = [agent.own_codes(level).view(-1, n) for level in agent.levels]
        codes = [_codes(agent, k, post[k], final[k], rows, fixed) for k in range(len(final))]
        redo = torch.zeros_like(invoked[:, 0])
        for k, level in enumerate(agent.levels):
            redo |= invoked[:, level.depth + 1] & (codes[k] != used[k])
        if stop_early and not bool(redo.any()):
            break  # (``codes`` are the final ones: no choice changes after this)
        now = ex.stack.tensors()
        ex.rewind(_restored(now, before, redo), redo if acting is None else redo & acting)
        ctx = recoded(agent, ctx, _with_codes(agent, rows, codes))
        action = ex.act(ctx, same_draws(agent.policy), agent.schedule_clock)
        invoked = torch.where(redo[:, None], ex.invoked, invoked)
        used = codes
    else:
        final = [agent.own_codes(level).view(-1, n) for level in agent.levels]
        codes = [_codes(agent, k, post[k], final[k], rows, fixed) for k in range(len(final))]
    ex.invoked = invoked
    if not stop_early or targets_needed(agent, batch, codes, used):
        ctx = recoded(agent, ctx, _with_codes(agent, rows, codes))  # the targets' codes
    return action, ctx


def targets_needed(agent, batch, codes: list, used: list) -> bool:
    """Whether a learning target reads a value that the codes ``codes`` change (a host read).

    The context holds the values at ``used``; a row whose codes differ now did not choose at
    a cooperation level since (its choice would have been made again), so where the learner
    reads values only at the levels that learn (``targets_at_finished_levels``) only its
    levels at or above a cooperative subtask that learn this step read changed values. No
    transitions (``batch`` ``None``, a greedy evaluation): none.
    """
    if batch is None:
        return False
    changed = [c != u for c, u in zip(codes, used, strict=True)]
    if not agent.learner.targets_at_finished_levels:
        return any(bool(c.any()) for c in changed)
    top = max(level.depth for level in agent.levels) + 1
    learning = finished(batch[LEVEL])[:, :top].any(1)
    return any(bool((c & learning).any()) for c in changed)


def _changed(agent, rows, codes: list[torch.Tensor]) -> bool:
    """Whether ``codes`` differ from those of ``rows`` anywhere (a host read)."""
    return any(bool((rows[lv.key] != c).any()) for lv, c in zip(agent.levels, codes, strict=True))


def _codes(agent, k: int, post, final, rows, fixed: dict) -> torch.Tensor:
    """Level ``k``'s codes: broadcast in order, or the fixed ones of ``rows``."""
    if k in fixed:
        return rows[agent.levels[k].key]
    return seen_codes(agent, agent.levels[k], post, final)


def _with_codes(agent, rows, codes: list[torch.Tensor]):
    """``rows`` (shallow copy) with every cooperation level's code replaced."""
    out = rows.clone(False)
    for level, code in zip(agent.levels, codes, strict=True):
        out.set(level.key, code)
    return out


def _restored(fields: dict, before: dict, rows: torch.Tensor) -> dict:
    """``fields`` with the rows ``rows [B]`` taken from ``before`` (new tensors)."""
    out = {}
    for key, value in fields.items():
        old = before[key]
        if isinstance(value, torch.Tensor) and value.dim() and value.shape[0] == rows.shape[0]:
            mask = rows.view(-1, *([1] * (value.dim() - 1)))
            out[key] = torch.where(mask, old, value)
        else:
            out[key] = value
    return out
