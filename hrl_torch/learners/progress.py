"""A domain's progress while it learns: what a ``Monitor`` reports, and ``EpisodeBins``.

A ``Monitor`` (e.g. the ship domain's) sees every transition batch and says, per learner, how
many episodes ended and whether a schedule (``hrl_torch.modules.exploration.TriggeredEpsilon``)
should start. ``EpisodeBins`` keeps per-learner sums over consecutive blocks of events (e.g.
"successes per 1000 episodes", "low-level successes per 1000 executions"): each finished event gets
its index within its learner, so blocks are exact however many envs a learner runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import torch
from torch import nn


class Monitor(Protocol):
    """Domain knowledge about a hybrid's progress, fed every transition batch."""

    def observe(self, batch) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(episodes ended per learner [P], epsilon trigger per learner [P] bool)``."""
        ...


class EpisodeBins(nn.Module):
    """Per-learner sums of event values over consecutive blocks of ``size`` events.

    Args:
        n_learners: population size ``P``.
        size: events per block (e.g. 1000 episodes).
        n_bins: blocks kept; later events go to an overflow block.
        fields: names of the summed values (``count`` is kept too).
    """

    def __init__(self, n_learners: int, size: int, n_bins: int, fields: Sequence[str]) -> None:
        super().__init__()
        self.size, self.n_bins, self.fields = int(size), int(n_bins), list(fields)
        self.register_buffer("events", torch.zeros(n_learners, dtype=torch.long))
        self.register_buffer("sums", torch.zeros(len(self.fields) + 1, n_learners, n_bins + 1))

    def add(self, ended: torch.Tensor, values: dict[str, torch.Tensor]) -> None:
        """Add the events of the rows where ``ended [B]`` (rows grouped by learner).

        ``values``: ``{field: [B]}``; an event of row ``b`` is numbered after the learner's
        earlier events and after the events of rows ``< b`` of the same learner.
        """
        p = self.events.shape[0]
        per = ended.view(p, -1).long()
        rank = per.cumsum(1) - 1 + self.events[:, None]
        block = (rank // self.size).clamp(0, self.n_bins)
        flat = (torch.arange(p, device=ended.device)[:, None] * (self.n_bins + 1) + block).view(-1)
        weight = ended.float()
        stacked = torch.stack([weight] + [values[f].float() * weight for f in self.fields])
        self.sums.view(len(self.fields) + 1, -1).index_add_(1, flat, stacked)
        self.events += per.sum(1)

    def completed(self) -> torch.Tensor:
        """Blocks completed per learner ``[P]``."""
        return (self.events // self.size).clamp_max(self.n_bins)

    def block_means(self) -> dict[str, torch.Tensor]:
        """``{field: [P, n_bins]}`` mean value per event of each block (NaN while empty)."""
        count = self.sums[0, :, : self.n_bins]
        return {
            f: torch.where(
                count > 0, self.sums[k + 1, :, : self.n_bins] / count.clamp_min(1), torch.nan
            )
            for k, f in enumerate(self.fields)
        }
