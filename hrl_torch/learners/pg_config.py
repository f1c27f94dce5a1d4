"""``PGConfig``: the options of the policy-gradient learners (``pg.py``; split for its length).

``hrl_torch.learners.pg.PGConfig`` and ``hrl_torch.learners.PGConfig`` name it as before.
"""

from __future__ import annotations

from dataclasses import dataclass

from hrl_torch.modules.schedules import Schedule

__all__ = ["PGConfig"]


@dataclass
class PGConfig:
    """Options of the policy-gradient learners.

    Attributes:
        alpha: step size ``alpha_k`` (number or schedule over env steps per learner).
        sigma: standard deviation of the Gaussian heads (in the pre-squash space).
        action_low: lower end of a continuous action (after the sigmoid squash); ``None``
            (default): the env's ``action_bounds``, which the trainer reads at its start (an
            error when neither gives one: ``action_range.use_action_bounds``).
        action_high: upper end (``None`` with ``action_low``).
        online: Algorithm 3 line 16 every step (True) or the same sum once per renewal cycle
            (False, the default since 0.2.x: it allows the baselines).
        beta: eligibility discount, ``z_{k+1} = beta z_k + grad mu / mu``; 1 is Equation 5.3,
            ``beta < 1`` is Baxter & Bartlett's biased, lower-variance estimate (which lines
            11-16 of Algorithm 3 may be replaced with, Section 5.2).
        trace_len: likelihood-ratio terms kept per invocation; an invocation that selects more
            children than this raises (bound invocations with the executor's guard).
        init: initial value of every policy parameter.
        baseline: step size of ``b``, a running mean of the reward-to-go per learner and
            parameter group, subtracted from it: ``theta += alpha sum_n (R_n - b) grad mu / mu``
            over the cycle. A constant baseline keeps Equation 5.2 unbiased (``b`` moves only
            after the cycle used it) and cuts its variance. 0 (default): Algorithm 3 as written.
            Needs ``online=False`` (``R_n`` is known at the renewal).
        frozen: accumulate ``sum (R + r~) z`` into ``grad_sum`` instead of changing ``theta``
            (gradient estimates for tests and diagnostics).
        value_rate: step size of a state baseline ``V(s)`` on the policy's own features (a
            table laid out like ``theta``, moved toward the reward-to-go by Monte Carlo):
            ``theta += alpha sum_n (R_n - V(s_n)) grad mu / mu`` over the cycle, unbiased
            (``pg_traces.value_baseline_traces``). ``None`` (default): 0.1 where it applies
            (``online=False``, no constant ``baseline``, not ``frozen``), else 0.
    """

    alpha: float | Schedule = 0.01
    sigma: float = 1.0
    action_low: float | None = None
    action_high: float | None = None
    online: bool = False
    beta: float = 1.0
    trace_len: int = 256
    init: float = 0.0
    baseline: float = 0.0
    frozen: bool = False
    value_rate: float | None = None

    def __post_init__(self) -> None:
        if self.baseline and self.online:
            raise ValueError("PGConfig.baseline needs online=False (the reward-to-go)")
        excluded = self.online or self.baseline or self.frozen
        if self.value_rate is None:  # (issue 33: the state baseline wherever it applies)
            self.value_rate = 0.0 if excluded else 0.1
        if self.value_rate < 0 or (self.value_rate and excluded):
            raise ValueError(
                "PGConfig.value_rate must be >= 0 and needs online=False, no baseline, not "
                f"frozen (got value_rate={self.value_rate})"
            )
