"""Exact dynamic programming for small finite models: the ground truth learners are tested on.

Inputs are a ``TaskGraph`` and a ``FiniteModel``: transition probabilities ``P [S, A, S]``,
rewards ``r [S, A]`` and every full state's observation fields, so subtask predicates and
abstractions are evaluated for all states at once. All tables are float64 tensors.

**Decision states.** ``x = (k, s)``: non-primitive instance ``k`` is on top of the Task-Stack
after popping, in full state ``s``. An instance is a root path, so ``k`` is the whole stack
(the joint state ``X = Omega x S`` of Definition 3.6). From ``x`` the policy pushes children
(no time passes) down to a primitive ``p``; after its step to ``s'``, the shallowest instance of
``p``'s path that ended at ``s'`` (terminated, or ``p`` itself) pops with everything it called
(Section 3.2), and its parent is the next top. Only decision states reachable from the root at
the start states under *some* hierarchical policy are kept: that drops combinations the
hierarchy can never produce (e.g. a delivery subtask running with the other part on board).

**Policies** are tables ``[n_instances, max_states]`` of child slots per (instance, abstract
state) (``instance_table`` expands per-subtask tables). Where the table's child is not
available the first available child is taken (``TablePolicy`` does the same in the executor).

Functions:

- ``markov_chain_gain``: gain of every state of a finite Markov chain (multichain: each
  recurrent class has its own gain ``pi_C r``; transient states mix them by absorption).
- ``flatten``, ``policy_gain``, ``policy_value``: a hierarchical policy as a Markov chain over
  decision states; its global gain (Eq. 4.1) or its (discounted) value until the root ends.
- ``flat_optimal``: best gain over stationary policies of the flat MDP (relative value iteration).
- ``hierarchically_optimal``: best global gain over policies consistent with the hierarchy
  (Definition 3.3, Eq. 4.2): relative value iteration over decision states, where a decision is
  a primitive path through available children.
- ``recursively_optimal``: bottom-up, each subtask optimises its own criterion given its
  children's policies (Definition 3.4): the projected value (Definition 3.5, Eq. 3.3), i.e.
  total reward until it terminates, discounted by ``gamma`` (1: undiscounted) for non-root
  subtasks (what MAXQ-Q learns), and the gain of the root's SMDP (Section 4.2.1) for a continuing
  root. RAR (Section 4.2.2) instead maximises each subtask's own gain ``E[R]/E[N]`` per
  invocation under its start distribution; both prefer shorter invocations when a subtask ends
  with a positive reward (e.g. a delivery), but for subtasks whose every step costs the same
  the gain is the same for all terminating policies, so RAR is indifferent where this
  criterion (and HH-learning's, reward minus a gain above -1 per step) picks the shortest way.
  Children are modelled as executed inside the parent: they also stop where the parent ends.
- ``check_abstractions``: Dietterich's conditions for safe state abstraction (max-node, leaf and
  result distribution irrelevance; termination and shielding as the exemptions they are),
  checked on every pair of states an abstraction merges and a policy can meet; one
  ``Violation`` (condition, subtask, child, the two full states, a message) per unsafe merge.
  See ``hrl_torch.analysis.abstraction`` for what is exact and what is sound but incomplete.
"""

from hrl_torch.analysis.abstraction import Violation, check_abstractions
from hrl_torch.analysis.chains import (
    ChainGain,
    FiniteModel,
    FlatResult,
    SolverOptions,
    flat_optimal,
    markov_chain_gain,
)
from hrl_torch.analysis.hierarchy import (
    FlatChain,
    HierarchicalResult,
    TablePolicy,
    flatten,
    hierarchically_optimal,
    instance_table,
    policy_gain,
    policy_value,
)
from hrl_torch.analysis.recursive import RecursiveResult, recursively_optimal

__all__ = [
    "ChainGain",
    "FiniteModel",
    "FlatChain",
    "FlatResult",
    "HierarchicalResult",
    "RecursiveResult",
    "SolverOptions",
    "TablePolicy",
    "Violation",
    "check_abstractions",
    "flat_optimal",
    "flatten",
    "hierarchically_optimal",
    "instance_table",
    "markov_chain_gain",
    "policy_gain",
    "policy_value",
    "recursively_optimal",
]
