"""A sampled leaf-irrelevance check while training (Dietterich 2000, Section 5.1).

A primitive's value ``V(a, s)`` is kept per *abstract* state. That is safe (leaf irrelevance)
only if the expected reward of ``a`` is the same in every full state the abstraction merges; if
it is not, the value averages rewards of different states and the policy above it can settle on
a loop (e.g. a move whose goal bonus is averaged over the whole grid looks good everywhere).
``hrl_torch.analysis.check_abstractions`` checks this exactly on a finite model; this monitor
checks it on the rewards training sees: per learner, primitive and abstract state, the lowest
and highest reward. A spread above ``tolerance`` is reported.

A primitive with a stochastic reward (or, in continuous time, a reward that grows with a random
duration) is reported too: the sample cannot tell a state-dependent mean from noise. Use it on
deterministic-reward domains, or read its reports as "check this abstraction".
"""

from __future__ import annotations

import warnings

import torch

from hrl_torch.execution.transitions import PRIMITIVE
from hrl_torch.hierarchy.graph import TaskGraph


class LeafRewardMonitor:
    """Lowest and highest reward of every (learner, primitive, abstract state) seen.

    Args:
        graph: the task graph.
        n_learners: ``P``.
        tolerance: a spread ``high - low`` above this is reported.
    """

    def __init__(self, graph: TaskGraph, n_learners: int, tolerance: float = 1e-6, device="cpu"):
        self.graph, self.tolerance = graph, tolerance
        self.n_states = max(graph.nodes[k].n_states for k in range(graph.n_nodes))
        shape = (n_learners * graph.n_nodes * self.n_states,)
        self.low = torch.full(shape, torch.inf, device=device)
        self.high = torch.full(shape, -torch.inf, device=device)
        self.reported: set[tuple[int, int]] = set()  # (primitive, abstract state)

    def observe(self, batch, learner_of_row: torch.Tensor) -> None:
        """Account the primitive steps of one step's transitions (``batch[PRIMITIVE]``)."""
        prim = batch[PRIMITIVE]
        cell = (learner_of_row * self.graph.n_nodes + prim["node"]) * self.n_states + prim["state"]
        reward = prim["reward"].float()
        valid = prim["valid"]
        self.low.scatter_reduce_(0, cell, reward.masked_fill(~valid, torch.inf), "amin")
        self.high.scatter_reduce_(0, cell, reward.masked_fill(~valid, -torch.inf), "amax")

    def new_violations(self) -> list[str]:
        """One line per (primitive, abstract state) newly over the tolerance in any learner."""
        spread = self.high - self.low
        bad = (spread > self.tolerance) & spread.isfinite()
        lines = []
        for cell in bad.nonzero().flatten().tolist():
            p, rest = divmod(cell, self.graph.n_nodes * self.n_states)
            node, state = divmod(rest, self.n_states)
            if (node, state) in self.reported:
                continue
            self.reported.add((node, state))
            lines.append(
                f"leaf irrelevance: primitive {self.graph.names[node]!r} saw rewards from "
                f"{float(self.low[cell]):.4g} to {float(self.high[cell]):.4g} in its abstract "
                f"state {state} (learner {p}); if its expected reward depends on the merged "
                "states, give it an abstraction that separates them"
            )
        return lines

    def warn(self) -> None:
        """Warn once about each primitive and abstract state newly over the tolerance."""
        for line in self.new_violations():
            warnings.warn(line, stacklevel=3)  # the trainer's caller
