"""A continuous PG node's action range: from its head or ``PGConfig``, or from the env.

A Gaussian head (tile-coded, or ``MLPGaussianPolicyHead``) squashes its sample into ``[low,
high]`` (``squash``), entry by entry. Before 0.2.x the tile-coded range defaulted to the ship's
+-15 deg/s whatever the task, and ``MLPGaussianPolicyHead``'s did before 0.2.1; now a head made
without one (``PGConfig(action_low=None)``, the default) takes the env's ``action_bounds`` when
the trainer starts, and training on an env without ``action_bounds`` is an error naming both
ways to give one.
"""

from __future__ import annotations

import warnings

from hrl_torch.modules.policies import ActionRange

__all__ = ["use_action_bounds"]


def use_action_bounds(learner, env) -> None:
    """Give every Gaussian head of ``learner`` without a range ``env.action_bounds``.

    ``env.action_bounds``: ``([low, ...], [high, ...])`` per action dimension; a Gaussian head
    drives ``action_dim`` of them (one, for the tile-coded head), so the env must have as
    many. Raises ``ValueError`` when a head has no range and the env gives none (or another
    number of dimensions). A head whose older version had a silent default the env's range
    differs from warns (``DeprecationWarning``).
    """
    pending = [m for m in learner.modules() if isinstance(m, ActionRange) and m.low is None]
    if not pending:
        return
    names = ", ".join(repr(m.name) for m in pending)
    hints = " or ".join(sorted({m.range_hint for m in pending}))
    bounds = getattr(env, "action_bounds", None)
    if bounds is None:
        raise ValueError(
            f"PG node(s) {names}: no action range: give {hints} "
            f"or an env with action_bounds ({type(env).__name__} has none)"
        )
    low, high = ([float(v) for v in b] for b in bounds)
    for head in pending:
        if len(low) != head.action_dim or len(high) != head.action_dim:
            raise ValueError(
                f"PG node(s) {head.name!r}: the env's action_bounds have {len(low)} dimensions; "
                f"the Gaussian head drives {head.action_dim}: give {head.range_hint}"
            )
        old = getattr(head, "old_default", None)
        if old is not None and any((a, b) != old for a, b in zip(low, high, strict=True)):
            warnings.warn(
                f"Gaussian head {head.name!r} was made without an action range: it now takes "
                f"the env's action_bounds ({low}, {high}), no longer {old}; give "
                f"{head.range_hint} to choose (this warning goes in 0.3.0)",
                DeprecationWarning,
                stacklevel=2,
            )
        one = head.action_dim == 1
        head.set_range(low[0] if one else low, high[0] if one else high)
