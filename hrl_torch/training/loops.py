"""Greedy episodes that run into the step limit, and the cycle of states they loop in.

A frozen greedy policy that never ends its episode repeats a cycle (a wall bump, two subtasks
handing control back and forth): the evaluation marks every episode that hit the step limit
and names the cycle. ``RecentStates`` keeps the last ``LOOP_WINDOW`` observations of each
row (its discrete fields, one column each), written by ``EvalEpisodes.add`` with no read of
the device; ``cycle`` finds the shortest period that repeats through that window, and
``describe`` writes the cycle's observations as ``field=value`` text. The evaluation record
(``eval_episodes.csv``'s ``loop`` column), ``summary.json`` (``final_eval_step_limit``) and
the progress line (``limit_note``) carry them.
"""

from __future__ import annotations

import torch

#: observations kept per row: cycles up to half of it are found
LOOP_WINDOW = 16
#: fields of a step that are not observations
_NOT_STATE = frozenset({"reward", "duration", "terminated", "truncated", "is_init", "acting"})


class RecentStates:
    """The discrete observation fields of a step as one ``[B, F]`` long tensor.

    The fields (integer and bool leaves, nested ones such as a multi-agent ``agents`` row's
    by their dotted names) are fixed at the first step; ``names`` says what each column is.
    """

    def __init__(self) -> None:
        self.keys: list[tuple[str, ...]] | None = None
        self.names: list[str] = []
        self.plain = False

    def codes(self, td) -> torch.Tensor:
        """``[B, F]`` long: the step's discrete fields (``td``: a TensorDict or its entries)."""
        if self.keys is None:
            self.keys, self.names = _discrete_keys(td)
            self.plain = bool(self.keys) and all(
                _get(td, k).dim() == 1 and _get(td, k).dtype == torch.long for k in self.keys
            )
        if self.plain:  # (one op: every field is a [B] long)
            return torch.stack([_get(td, key) for key in self.keys], 1)
        b = td["reward"].shape[0]
        parts = [_get(td, key).reshape(b, -1).long() for key in self.keys]
        if not parts:
            return torch.zeros(b, 0, dtype=torch.long, device=td["reward"].device)
        return torch.cat(parts, 1)


def _discrete_keys(td) -> tuple[list[tuple[str, ...]], list[str]]:
    keys, names = [], []
    for key, value in sorted(td.items(), key=lambda kv: str(kv[0])):
        if key in _NOT_STATE:
            continue
        if hasattr(value, "items"):  # a nested TensorDict (each agent's fields)
            inner, inner_names = _discrete_keys(value)
            keys += [(key, *k) for k in inner]
            names += [f"{key}.{n}" for n in inner_names]
        elif isinstance(value, torch.Tensor) and not value.is_floating_point():
            width = value[0].numel() if value.dim() > 1 else 1
            keys.append((key,))
            names += [key] if width == 1 else [f"{key}[{j}]" for j in range(width)]
    return keys, names


def _get(td, key: tuple[str, ...]):
    for k in key:
        td = td[k]
    return td


def cycle(states: torch.Tensor) -> int:
    """The shortest period ``p`` with ``states[t] == states[t - p]`` through ``states [n, F]``.

    ``0`` when none up to ``n // 2`` repeats over the whole window (no cycle seen).
    """
    n = states.shape[0]
    for p in range(1, n // 2 + 1):
        if torch.equal(states[p:], states[:-p]):
            return p
    return 0


def describe(states: torch.Tensor, names: list[str]) -> str:
    """One observation per line-part: ``a=1 b=2 -> a=1 b=3`` (columns by ``names``)."""
    return " -> ".join(
        " ".join(f"{n}={v}" for n, v in zip(names, row.tolist(), strict=True)) for row in states
    )


class Loops:
    """Per row, the cycle a truncated episode looped in (``""`` for the others), made lazily.

    Args:
        ring: ``[N, W, F]`` the last observations of each row at slot ``t % W`` (``t`` the
            step's index in the episode), on the CPU.
        length: ``[N]`` the episodes' steps.
        truncated: ``[N]`` the episodes that hit the step limit.
        names: the ``F`` fields' names.
    """

    def __init__(self, ring, length, truncated, names) -> None:
        self.ring, self.length, self.truncated, self.names = ring, length, truncated, names
        self._texts: list[str] | None = None

    def __len__(self) -> int:
        return self.ring.shape[0]

    def __getitem__(self, row: int) -> str:
        return self.texts()[row]

    def __iter__(self):
        return iter(self.texts())

    def texts(self) -> list[str]:
        """Every row's text (computed once)."""
        if self._texts is None:
            self._texts = [""] * len(self)
            for r in self.truncated.nonzero().flatten().tolist():
                self._texts[r] = self._text(r)
        return self._texts

    def _text(self, r: int) -> str:
        window, length = self.ring.shape[1], int(self.length[r])
        n = min(length, window)
        if n == 0:
            return "no step played"
        if self.ring.shape[2] == 0:
            return "hit the step limit (no discrete observation fields to show)"
        seen = self.ring[r, torch.arange(length - n, length) % window]
        p = cycle(seen)
        if p:
            return f"{p}-step cycle: {describe(seen[-p:], self.names)}"
        return f"no cycle within the last {n} steps; last: {describe(seen[-1:], self.names)}"


def limit_note(records, loops: list[str], most: int = 1) -> str:
    """``"; 3 greedy episodes hit the step limit (seed 0 episode 4: ...)"`` or ``""``."""
    hit = records["truncated"].nonzero().flatten().tolist()
    if not hit:
        return ""
    named = [
        f"seed {int(records['seed'][r])} episode {int(records['episode'][r])}: {loops[r]}"
        for r in hit[:most]
    ]
    more = f"; {len(hit) - most} more in eval_episodes.csv" if len(hit) > most else ""
    return f"; {len(hit)} greedy episode(s) hit the step limit ({'; '.join(named)}{more})"
