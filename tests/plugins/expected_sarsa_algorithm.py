"""A plugin that registers one new tabular learner and no domain.

``hrl-torch --domain-module expected_sarsa_algorithm train taxi --algo expected-sarsa`` then runs
it on every built-in domain that offers a tabular, single-agent, episodic task (taxi, four-rooms,
key-door, ...) with that domain's own budget, exploration and initial values; agents/ is not
touched (tests/test_algorithms.py).
"""

from hrl_torch.runs.algorithms import Algorithm, register_algorithm
from tests.test_new_learner import ExpectedSarsa

register_algorithm(
    Algorithm(
        "expected-sarsa",
        ExpectedSarsa,
        settings={"alpha": 0.5, "epsilon": 0.1},
        description="SMDP Expected SARSA at every subtask (a plugin)",
    )
)
