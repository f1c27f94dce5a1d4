"""Update rules over SMDP transition batches."""

from hrl_torch.learners.average_reward import GainEstimate, HARLearner, RARLearner
from hrl_torch.learners.base import Learner, TabularLearner, ValuePolicy
from hrl_torch.learners.hdr import HDRLearner
from hrl_torch.learners.hh_learning import HHLearner
from hrl_torch.learners.maxq import MaxQLearner
from hrl_torch.learners.pg import ActorCriticLearner, HPGRLLearner, PGConfig, PGPolicy
from hrl_torch.learners.q_lambda import QLambdaLearner
from hrl_torch.learners.q_learning import SMDPQLearner
from hrl_torch.learners.rule import RuleLearner
from hrl_torch.learners.rvi_q import RVIQLearner

__all__ = [
    "ActorCriticLearner",
    "GainEstimate",
    "HARLearner",
    "HDRLearner",
    "HHLearner",
    "HPGRLLearner",
    "Learner",
    "MaxQLearner",
    "PGConfig",
    "PGPolicy",
    "QLambdaLearner",
    "RARLearner",
    "RuleLearner",
    "RVIQLearner",
    "SMDPQLearner",
    "TabularLearner",
    "ValuePolicy",
]
