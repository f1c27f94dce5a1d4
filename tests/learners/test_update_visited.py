"""All-states updating writes each bank's own entries of a shared store (``update_visited``).

The three-part learners keep ``C``, ``V`` and ``CE`` in one store; their all-states block once
wrote ``CE``'s targets through ``C``'s indices (into ``C``), which left ``CE`` at the visited
states untouched.
"""

import torch
from tensordict import TensorDict

from hrl_torch.execution.transitions import LEVEL
from hrl_torch.learners import HDRLearner
from tests.learners.test_q_lambda_and_hh_exact import chain


def test_update_visited_moves_each_bank_of_a_shared_store_at_the_visited_state():
    graph, _ = chain()
    learner = HDRLearner(graph, 2, alpha=1.0, gamma=0.9)
    root, go2 = graph.index["Root"], 0  # Root's first child slot: Go2
    d = graph.max_levels
    one = torch.ones(1, d, 1, dtype=torch.bool)
    level = TensorDict(
        {
            "visited_valid": one,
            "visited_steps": torch.ones(1, d, 1, dtype=torch.long),
            "visited_state": torch.full((1, d, 1), 1),
            "child": torch.full((1, d), go2),
        },
        batch_size=[1, d],
    )
    batch = TensorDict({"learner": torch.tensor([1]), LEVEL: level}, batch_size=[1])
    table = torch.full((1, d), root)
    valid = torch.zeros(1, d, dtype=torch.bool)
    valid[0, 0] = True  # the root's level only
    c, ce = torch.full((1, d, 1), 3.0), torch.full((1, d, 1), -2.0)
    learner.update_visited(batch, table, valid, 1.0, [(learner.C, c), (learner.CE, ce)])
    assert float(learner.C.view(root, 1)[1, go2]) == 3.0
    assert float(learner.CE.view(root, 1)[1, go2]) == -2.0
    # nothing else moved: learner 0, the other states and children
    assert int((learner.C.data != 0).sum()) == 1 and int((learner.CE.data != 0).sum()) == 1
