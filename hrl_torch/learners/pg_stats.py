"""What a PG subtask is doing, per learner and parameter group, for TensorBoard (issue 33).

At each training log ``HPGRLLearner.log_scalars`` gives, per PG group ``g`` (a subtask, or the
nodes that share its parameters), one value per seed:

- ``hrl/<g>/return_per_invocation``: the mean of ``sum (R + r~)`` over the invocations that
  ended since the last log (the undiscounted return each invocation collected, internal
  rewards included: what Algorithm 3 ascends);
- ``hrl/<g>/policy_mean``, ``hrl/<g>/policy_spread``, ``hrl/<g>/policy_sigma`` (Gaussian
  heads): the action of the mean tile weight (``squash(mean w)``, in action units), the spread
  of the tile weights (pre-squash: how much the mean action varies over states) and the
  sampling width ``sigma``; ``hrl/<g>/policy_entropy`` (softmax heads): the mean entropy of
  the policy rows over the abstract states; MLP heads (``neural_policies``, their weights are
  no tile means or logits): ``hrl/<g>/weight_norm``, the norm of the weights (and ``sigma``);
- ``losses/<g>/update_norm``: ``||theta_g - theta_g at the last log||``; ``losses/<g>/step_size``:
  ``alpha`` now; ``losses/<g>/gradient_norm``: the update's norm over ``alpha`` (the norm of the
  summed gradient estimates ``sum (R - b) z`` since the last log, for a constant ``alpha``).

Success per subtask is the trainer's ``hrl/<subtask>/success`` (every subtask has it). The
returns are summed on the device in ``update`` (a few ops, no host read); everything else is
read from the parameters at the log.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from hrl_torch.modules.neural_policies import MLPPolicyHead
from hrl_torch.modules.policies import TileGaussianPolicyHead, squash

__all__ = ["PGStats"]


class PGStats(nn.Module):
    """Invocation returns since the last log ``[2, P * G]`` (sum, count) and ``theta`` then.

    Args:
        n_learners: table sets ``P``.
        theta: the learner's flat parameters (copied: the reference for the update's norm).
        n_groups: parameter groups ``G``.
    """

    def __init__(self, n_learners: int, theta: torch.Tensor, n_groups: int) -> None:
        super().__init__()
        self.n_learners, self.n_groups = n_learners, n_groups
        # (saved: a resumed run logs what the uninterrupted one does)
        self.register_buffer("returns", torch.zeros(2, n_learners * n_groups))
        self.register_buffer("theta_at_log", theta.detach().clone())

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        for name in ("returns", "theta_at_log"):  # checkpoints of 0.1 have no statistics
            state_dict.setdefault(prefix + name, getattr(self, name).clone())
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def record(self, reward: torch.Tensor, count: torch.Tensor, ended, cell) -> None:
        """Add the returns of the invocations ``ended [B, S]`` to their (learner, group) ``cell``.

        ``reward [B, S, K + 1]``: each pair's ring of ``R + r~`` (the first ``count [B, S]``
        entries are this invocation's).
        """
        slots = torch.arange(reward.shape[-1], device=reward.device)
        total = (reward * (slots < count[..., None])).sum(-1)
        done = ended.to(reward.dtype)
        self.returns.index_add_(1, cell.reshape(-1), torch.stack([total * done, done]).flatten(1))

    def scalars(self, learner, step: int) -> dict[str, list[float]]:
        """The tags of the module docstring, one value per learner; then restart the sums."""
        sums = self.returns.view(2, self.n_learners, self.n_groups)
        mean_return = torch.where(sums[1] > 0, sums[0] / sums[1].clamp_min(1.0), torch.nan)
        alpha = learner.alpha(step)
        alphas = (
            alpha.double().tolist()
            if isinstance(alpha, torch.Tensor)
            else [float(alpha)] * self.n_learners
        )
        out: dict[str, list[float]] = {}
        theta, before = learner.params.store, self.theta_at_log
        for t, name in enumerate(learner.group_names):
            head = learner.heads[name]
            block = learner.params.block(t)  # [P, n_states, n_cols] (a view of theta)
            start = int(learner.params.offset[t])
            size = block.shape[1] * block.shape[2]
            rows = torch.arange(self.n_learners, device=theta.device)[:, None] * learner.total
            at = (rows + start + torch.arange(size, device=theta.device)).reshape(-1)
            moved = (theta[at] - before[at]).view(self.n_learners, size).norm(dim=1).tolist()
            out[f"hrl/{name}/return_per_invocation"] = mean_return[:, t].tolist()
            out[f"losses/{name}/update_norm"] = moved
            out[f"losses/{name}/step_size"] = alphas
            out[f"losses/{name}/gradient_norm"] = [
                m / a if a > 0 else math.nan for m, a in zip(moved, alphas, strict=True)
            ]
            if isinstance(head, TileGaussianPolicyHead):
                w = block[:, 0, :]
                mean = w.mean(-1)
                if head.low is not None:
                    out[f"hrl/{name}/policy_mean"] = squash(mean, head.low, head.high).tolist()
                out[f"hrl/{name}/policy_spread"] = w.std(-1, correction=0).tolist()
                out[f"hrl/{name}/policy_sigma"] = [head.sigma] * self.n_learners
            elif isinstance(head, MLPPolicyHead):  # (weights, not tile means or logits)
                out[f"hrl/{name}/weight_norm"] = block.flatten(1).norm(dim=1).tolist()
                if head.continuous:
                    out[f"hrl/{name}/policy_sigma"] = [head.sigma] * self.n_learners
            else:
                logits = block[:, :, : head.n_children]
                p = torch.softmax(logits, -1)
                entropy = -(p * torch.log_softmax(logits, -1)).sum(-1).mean(-1)
                out[f"hrl/{name}/policy_entropy"] = entropy.tolist()
        self.returns.zero_()
        self.theta_at_log.copy_(theta)
        return out
