"""HDR: hierarchically optimal discounted reward RL (Section 4.3.1).

MAXQ-Q (Dietterich 2000) extended with the three-part value decomposition of Andre and Russell
(2002): every non-primitive instance keeps a completion ``C`` and an external completion ``CE``,
and chooses its child by ``V + C + CE``, the discounted value of the whole Task-Stack above it
(see ``hrl_torch.learners.three_part`` for the equations). Discounting is ``gamma**t`` with
``t`` the primitive steps ``N`` (discrete time) or the duration ``tau`` (continuous time); a
primitive learns its immediate reward (Dietterich's ``V(a, s) <- (1-alpha) V + alpha r``; in
continuous time the step's lump reward plus rate times ``tau``, as the env reports it).
"""

from __future__ import annotations

import torch

from hrl_torch.common.ops import discount
from hrl_torch.execution.transitions import PRIMITIVE
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.learners.three_part import ThreePartLearner
from hrl_torch.modules.schedules import Schedule


class HDRLearner(ThreePartLearner):
    """Hierarchically optimal discounted learning for a population of ``P`` learners.

    Args:
        graph: the task graph.
        n_learners: population size ``P``.
        alpha: step size (number or schedule).
        gamma: discount factor (per step, or per time unit in continuous time).
        all_states: all-states updating (needs the executor's ``record_visited``).
        continuous: discount by durations ``tau`` instead of primitive steps ``N``.
        init: initial completion values ``C``.
        ce_init: initial external completions ``CE`` (default: ``init``).
    """

    def __init__(
        self,
        graph: TaskGraph,
        n_learners: int,
        alpha: float | Schedule = 0.5,
        gamma: float = 0.95,
        all_states: bool = False,
        continuous: bool = False,
        init: float = 0.0,
        ce_init: float | None = None,
    ) -> None:
        super().__init__(graph, n_learners, alpha, gamma, all_states, continuous, init, ce_init)

    def discount(self, t: torch.Tensor) -> torch.Tensor:
        """``gamma ** t`` (``hrl_torch.common.ops.discount``: float64 inside, shape-independent)."""
        return discount(self.gamma, t)

    def primitive_target(self, batch) -> torch.Tensor:
        """The step's reward."""
        prim = batch[PRIMITIVE]
        return prim["reward"]
