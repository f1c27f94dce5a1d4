"""Update rules over SMDP transition batches."""

from hrl_torch.learners.base import Learner, TabularLearner, ValuePolicy
from hrl_torch.learners.maxq import MaxQLearner
from hrl_torch.learners.q_learning import SMDPQLearner

__all__ = ["Learner", "MaxQLearner", "SMDPQLearner", "TabularLearner", "ValuePolicy"]
