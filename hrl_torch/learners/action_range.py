"""A continuous PG node's action range: from its ``PGConfig`` or from the env, never a guess.

A tile-coded Gaussian head squashes its sample into ``[low, high]`` (``squash``). Before 0.2.x
the range defaulted to the ship's +-15 deg/s whatever the task; now a head made without one
(``PGConfig(action_low=None)``, the default) takes the env's ``action_bounds`` when the trainer
starts, and training on an env without ``action_bounds`` is an error naming both ways to give
one.
"""

from __future__ import annotations

from hrl_torch.modules.policies import TileGaussianPolicyHead

__all__ = ["use_action_bounds"]


def use_action_bounds(learner, env) -> None:
    """Give every Gaussian head of ``learner`` without a range ``env.action_bounds``.

    ``env.action_bounds``: ``([low, ...], [high, ...])`` per action dimension; a Gaussian head
    drives one dimension, so the env must have one. Raises ``ValueError`` when a head has no
    range and the env gives none (or gives several dimensions).
    """
    pending = [
        m for m in learner.modules() if isinstance(m, TileGaussianPolicyHead) and m.low is None
    ]
    if not pending:
        return
    names = ", ".join(repr(m.name) for m in pending)
    bounds = getattr(env, "action_bounds", None)
    if bounds is None:
        raise ValueError(
            f"PG node(s) {names}: no action range: give PGConfig(action_low=..., "
            f"action_high=...) or an env with action_bounds ({type(env).__name__} has none)"
        )
    low, high = bounds
    if len(low) != 1 or len(high) != 1:
        raise ValueError(
            f"PG node(s) {names}: the env's action_bounds have {len(low)} dimensions; a "
            "Gaussian head drives one: give PGConfig(action_low=..., action_high=...)"
        )
    for head in pending:
        head.set_range(float(low[0]), float(high[0]))
