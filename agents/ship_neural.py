"""The ship's hybrid with MLP Gaussian subtasks: a tabular Q(lambda) root over neural policies.

The same hierarchy, root and HPGRL estimator as ``agents.ship_learners.make_hybrid`` (Section
5.3); only the two low-level subtasks' policies differ: the tile-coded Gaussian (9 tilings of 5 x
5 x 36 x 5 over the local state) becomes ``MLPGaussianPolicyHead``, an MLP over the same four
local features scaled into [-1, 1], whose score comes from autograd
(``hrl_torch.modules.neural_policies``).
"""

from __future__ import annotations

from agents.ship import (
    LOCAL_SIZE,
    LOW_LEVEL_GUARD,
    SUBTASK_NAMES,
    direction_groups,
    low_level_feature_rewards,
)
from agents.ship_learners import PARAMS, ShipHyperparams, ShipMonitor
from envs.ship import MAX_TURN
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.learners.hybrid import HybridLearner
from hrl_torch.learners.pg import HPGRLLearner, PGConfig
from hrl_torch.learners.q_lambda import QLambdaLearner
from hrl_torch.modules.exploration import TriggeredEpsilon
from hrl_torch.modules.neural_policies import MLPGaussianPolicyHead


def mlp_heads(
    sigma: float,
    hidden: int | tuple[int, ...] = 32,
    adam_lr: float | None = None,
    wrap_heading: bool = False,
) -> dict[str, MLPGaussianPolicyHead]:
    """One MLP Gaussian head per low-level subtask, over its four local features.

    ``wrap_heading``: the heading as its sine and cosine (one turn is -180 .. 180 degrees).
    """
    low, high = [0.0, 0.0, -180.0, -MAX_TURN], [LOCAL_SIZE, LOCAL_SIZE, 180.0, MAX_TURN]
    wrap = [False, False, True, False] if wrap_heading else None
    return {
        name: MLPGaussianPolicyHead(
            name, 4, hidden, sigma, -MAX_TURN, MAX_TURN, low, high, wrap=wrap, adam_lr=adam_lr
        )
        for name in SUBTASK_NAMES
    }


def make_hybrid_mlp(
    graph: TaskGraph,
    n_learners: int,
    params: ShipHyperparams = PARAMS,
    hidden: int | tuple[int, ...] = 32,
    pg_alpha: float = 0.001,
    adam_lr: float | None = None,
    wrap_heading: bool = False,
) -> HybridLearner:
    """The hybrid with MLP Gaussian low-level subtasks.

    ``pg_alpha``: their step size (Algorithm 3 line 16), or with ``adam_lr`` Adam's over the
    same estimate; ``wrap_heading``: the heading enters as its sine and cosine.
    """
    value = QLambdaLearner(graph, n_learners, params.q_alpha, params.lam, nodes=["Root"])
    config = PGConfig(
        alpha=pg_alpha,
        sigma=params.sigma,
        online=params.online,
        beta=params.pg_beta,
        baseline=params.pg_baseline,
        trace_len=LOW_LEVEL_GUARD,
        value_rate=0.0,
    )
    pg = HPGRLLearner(
        graph,
        n_learners,
        config,
        direction_groups(),
        heads=mlp_heads(params.sigma, hidden, adam_lr, wrap_heading),
        feature_reward=low_level_feature_rewards(),
    )
    epsilon = TriggeredEpsilon(
        n_learners, params.epsilon, params.epsilon_factor, params.epsilon_every
    )
    monitor = ShipMonitor(graph, n_learners, trigger_rate=params.trigger_rate)
    return HybridLearner(graph, n_learners, value, pg, epsilon, monitor)
