"""The descent: from each row's top instance down to a primitive, by a policy's choices.

``HierarchicalExecutor.act`` asks a ``Descent`` for the instance that ends on top of every
stack: ``follow`` walks the choices of every choosing instance at once (a ``ChoosesAll``
policy), ``level_by_level`` asks the policy's ``select`` once per stack level (any policy; on
large CPU batches a ``SelectsRows`` policy's ``select_rows`` for the choosing rows only). The
executor then pushes the new path (``HierarchicalExecutor._push``).
"""

from __future__ import annotations

import functools
from dataclasses import replace

import torch

from hrl_torch.execution.transitions import Choice, SelectsRows, as_choice, is_kind
from hrl_torch.hierarchy.graph import StepContext, TaskGraph
from hrl_torch.hierarchy.subtask import GraphError


class Descent:
    """The index tables of one executor's descents (``B`` rows over one graph).

    Args:
        graph: the task graph.
        batch_size: ``B``.
        score_width: width ``K`` of the likelihood-ratio terms the executor keeps.
    """

    def __init__(self, graph: TaskGraph, batch_size: int, score_width: int = 0) -> None:
        g, device = graph, graph.node_children.device
        long = dict(dtype=torch.long, device=device)
        self.graph, self.batch_size, self.score_width = graph, batch_size, score_width
        self.depth, self.device = graph.max_levels, device
        rows = torch.arange(batch_size, **long)
        self._row_base = rows * graph.n_nodes  # row b's block in a flat [B * N, ...]
        # the index bases of ``follow``: each row's block of choices, codes, flags
        ic, codes = g.n_choosers, g.n_choosers + g.n_instances + 1
        self._chooser_base = (torch.arange(ic, **long) * g.max_children)[None, :]
        self._leaf_codes = torch.arange(ic, codes, **long).expand(self.batch_size, -1)
        self._code_base = rows * codes
        self._greedy_base = rows[:, None] * (ic + 1)
        self._every_row = torch.ones(batch_size, dtype=torch.bool, device=device)
        # the depth at which each instance + 1 chooses (-1: a primitive or none)
        self._chooses_at_1 = torch.where(g.inst_composite_1, g.inst_depth_1, -1)

    def follow(self, code: torch.Tensor, choice: Choice, greedy: bool = True):
        """Follow the choices of every choosing instance ``[B, Ic]`` down to a primitive.

        ``code [B]``: where each row's descent starts (``HierarchicalExecutor``'s start code).

        Returns the instance on top + 1 ``[B]`` and each level's choice greedy flag on the
        new stack ``[B, D]`` (True where nothing was chosen; ``None`` without ``greedy``).
        """
        g, ic = self.graph, self.graph.n_choosers
        nxt = torch.take(g.chooser_next_code, self._chooser_base + choice.child)
        nxt = torch.cat([nxt, self._leaf_codes], 1)  # a primitive stays where it is
        for _ in range(self.depth - 1):
            code = torch.take(nxt, self._code_base + code)  # (take reads nxt flat)
        top1 = code - ic
        if not greedy:
            return top1, None
        flags = torch.nn.functional.pad(choice.greedy, (0, 1), value=True)
        own = torch.take(flags, self._greedy_base + g.path_chooser_1.index_select(0, top1))
        return top1, own

    def level_by_level(
        self, f, code, ctx, policy, step, new_features=None, compact_rows=1024, greedy=True
    ):
        """``follow`` with the policy's ``select`` asked once per level (any policy).

        The choice of the instance at depth ``d`` reads the row's random numbers of level
        ``d`` (``push=d``); a policy's scores and continuous actions are kept on the stack.
        ``new_features``: the features ``[B, N, F]`` of new invocations
        (``graph.start_features``), which the rows whose instance at ``d`` was pushed in this
        act choose from. From ``compact_rows`` rows on (CPU) a policy with ``select_rows``
        chooses for the rows that choose at a level only (the same choices, fewer values).
        ``f``: the stack's fields (their scores and continuous actions are updated). Returns
        what ``follow`` does (the greedy flags only with ``greedy``).
        """
        g = self.graph
        ic = g.n_choosers
        # back to instances + 1 (0: none)
        col = torch.where(code < ic, torch.take(g.choosers, code.clamp_max(ic - 1)) + 1, code - ic)
        compact = (
            is_kind(policy, SelectsRows)
            and self.device.type == "cpu"
            and self.batch_size >= compact_rows
        )
        flags, scores = [], []
        for level in range(self.depth - 1):
            chooses = torch.take(self._chooses_at_1, col) == level
            seen = ctx
            if new_features is not None:  # rows whose instance at this level started now
                started = (level > f["top"])[:, None, None]
                seen = replace(ctx, features=torch.where(started, new_features, ctx.features))
            if compact:  # (``choice`` only where a score or an action must be kept)
                choice, new_col, (rows, own) = self._choose_rows(
                    seen, policy, step, level, col, chooses
                )  # (the other rows count as greedy)
                flag = self._every_row.index_copy(0, rows, own) if greedy else None
            else:
                node = torch.take(g.inst_node_1, col)
                available = self._available_flat(ctx).index_select(0, self._row_base + node)
                choice = as_choice(
                    policy.select((col - 1).clamp_min(0), seen, available, step, level)
                )
                child = torch.take(g.inst_children_1, col * g.max_children + choice.child)
                new_col = torch.where(chooses, child, col)
                flag = (choice.greedy | ~chooses) if greedy else None
            if choice is not None and choice.score_index is not None:
                scores.append((level, chooses, choice))
            if g.action_dim:
                self._record_action(f, chooses & ~torch.take(g.inst_composite_1, new_col), choice)
            col = new_col
            flags.append(flag)
        if scores:
            self._record_scores(f, scores)
        if not greedy:
            return col, None
        return col, torch.stack([*flags, torch.ones_like(col, dtype=torch.bool)], 1)

    def _choose_rows(self, ctx, policy, step, level, col, chooses):
        """One level's choices, made for the rows that choose only: ``(choice, col, greedy)``.

        ``col``: each row's instance + 1 after the level (the chosen child where a row
        chooses); ``greedy``: the choosing rows ``[R]`` and whether each choice is greedy.
        ``choice`` holds every row's values (0, greedy, no score where a row does not choose)
        when the policy gave a score or an action (else ``None``: nothing reads it).
        """
        g = self.graph
        rows = chooses.nonzero().squeeze(1)
        inst1 = col.index_select(0, rows)
        node = torch.take(g.inst_node_1, inst1)
        available = self._available_flat(ctx).index_select(0, rows * g.n_nodes + node)
        part = as_choice(
            policy.select_rows((inst1 - 1).clamp_min(0), ctx, available, step, level, rows)
        )
        child = torch.take(g.inst_children_1, inst1 * g.max_children + part.child)
        new_col = col.index_copy(0, rows, child)  # (one op: the other rows keep theirs)
        if part.action is None and part.score_index is None:
            return None, new_col, (rows, part.greedy)

        def spread(values: torch.Tensor, fill=0) -> torch.Tensor:
            """``values [R, ...]`` at ``rows`` of a ``[B, ...]`` tensor of ``fill``."""
            out = values.new_full((col.shape[0], *values.shape[1:]), fill)
            return out.index_copy_(0, rows, values)  # (in place: a fresh tensor)

        out = Choice(spread(part.child), spread(part.greedy, True))
        if part.action is not None:
            out.action = spread(part.action)
        if part.score_index is not None:
            out.score_index, out.score_value = spread(part.score_index), spread(part.score_value)
        return out, new_col, (rows, part.greedy)

    def _available_flat(self, ctx: StepContext) -> torch.Tensor:
        """``ctx.available`` as ``[B * N, A]`` rows (row ``b * N + node``)."""
        return ctx.available.view(-1, self.graph.max_children)

    def _record_scores(self, f: dict, scores: list) -> None:
        """Keep each choice's likelihood-ratio term at its level, where the level chose.

        ``scores``: ``(level, chose [B], choice)`` of the levels whose choices carry terms;
        one write for all levels.
        """
        for _, _, choice in scores:
            if choice.score_index.shape[1] != self.score_width:
                raise ValueError(
                    f"the policy scored its choices with {choice.score_index.shape[1]} entries, "
                    f"the executor keeps score_width={self.score_width}"
                )
        old_index, old_value = f["score_index"], f["score_value"]
        by_level = {level: (chose, choice) for level, chose, choice in scores}
        none = torch.zeros_like(old_index[:, 0, 0], dtype=torch.bool)
        chose = torch.stack(
            [by_level[k][0] if k in by_level else none for k in range(self.depth)], 1
        )
        new = [by_level.get(k, (None, None))[1] for k in range(self.depth)]
        index = torch.stack([c.score_index if c else old_index[:, k] for k, c in enumerate(new)], 1)
        value = torch.stack([c.score_value if c else old_value[:, k] for k, c in enumerate(new)], 1)
        f["score_index"] = torch.where(chose[..., None], index, old_index)
        f["score_value"] = torch.where(chose[..., None], value, old_value)

    @staticmethod
    def _record_action(f: dict, pushed: torch.Tensor, choice: Choice | None) -> None:
        """The action vector of the continuous primitives pushed (``pushed [B]``)."""
        if choice is None or choice.action is None:
            raise GraphError("a continuous primitive was chosen without an action value")
        f["cont_action"] = torch.where(pushed[:, None], choice.action, f["cont_action"])


def level_spans(depth: int, depth_1: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The levels' roles in a push, by old and new top: ``(spans, code)``.

    ``spans[:, (old + 1) * (D + 1) + new + 1]`` is ``[4, D]``: the levels kept (below the old
    top), the ones that chose a child (old top .. new top - 1), the new invocations (above
    the old top up to the new one) and the fresh ones (either). (Roles first: a push's
    ``index_select(1, ...)`` gives each role as a contiguous ``[B, D]`` mask; a strided one
    makes a CPU ``where`` about four times slower.) ``code[top1]`` is
    ``depth + 1 + (D + 1)`` of the instance ``top1 - 1``, so that ``old * (D + 1) + code``
    is the column of ``spans``. (``spans`` is made once per depth: executors for evaluation
    subsets are built often; it is only read.)
    """
    return _spans(depth).to(depth_1.device), depth_1 + 1 + (depth + 1)


@functools.cache
def _spans(depth: int) -> torch.Tensor:
    lv = torch.arange(depth)
    rows = []
    for old in range(-1, depth):
        for new in range(-1, depth):
            kept = lv < old
            chose = ~kept & (lv < new)
            invoked = (lv > old) & (lv <= new)
            rows.append(torch.stack([kept, chose, invoked, chose | invoked]))
    return torch.stack(rows, 1)
