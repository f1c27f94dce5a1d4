"""Unmodified gymnasium toy-text envs through ``hrl_torch.env.adapters.GymnasiumBatchEnv``.

``FrozenLake-v1`` and ``FrozenLake8x8-v1`` (``is_slippery=False``) and ``CliffWalking-v1``
(made with ``max_episode_steps=200``: gymnasium registers it without a time limit), with flat
Q-learning only. Each has one fixed start and one fixed goal and no repeated sub-goal for a
subtask to share, so a hierarchy would only add a root decision (the four-rooms and key-door
domains are the hierarchical ones).

These domains run on the ``gymnasium`` backend only, so they are not registered with the
built-in domains (whose contract test builds every domain's torch env); use them with
``hrl-torch --domain-module agents.toy_text train frozenlake-8x8 --algo q --backend gymnasium``.

Rewards and the near-optimal greedy return (the threshold): FrozenLake pays 1 on reaching the
goal and nothing else (a hole ends the episode with 0), so every successful greedy episode
returns 1.0; without a step cost an undiscounted greedy policy can circle forever among states
of equal value, so these learners discount (``gamma`` 0.99). CliffWalking costs 1 per step and
100 for stepping into the cliff (back to the start); the shortest path returns -13.
"""

from __future__ import annotations

from agents.taxi import epsilon_first_third, flat_graph
from hrl_torch.common.config import Make
from hrl_torch.learners import SMDPQLearner
from hrl_torch.runs.domain import AlgoSpec, DomainSpec
from hrl_torch.training.config import TrainConfig

# The best settings of docs/defaults.md (scripts/defaults_table.py, 5 seeds). FrozenLake:
# optimistic values (+1, the goal's reward); pessimistic ones (-1) never reached the goal, as a
# hole (return 0) then beats every state not yet valued. CliffWalking: zero.
ALPHA = 0.5
INIT_FROZEN_LAKE = 1.0
INIT_CLIFF_WALKING = 0.0


def _make_env(env_id: str, **kwargs):
    def make_env(seeds, envs_per_learner: int, backend: str = "gymnasium"):
        if backend != "gymnasium":
            raise ValueError(f"{env_id} runs on the gymnasium backend only, not {backend!r}")
        import gymnasium

        from hrl_torch.env.adapters import GymnasiumBatchEnv

        return GymnasiumBatchEnv(lambda: gymnasium.make(env_id, **kwargs), seeds, envs_per_learner)

    return make_env


def _domain(name, env_id, *, n_states, gamma, init, optimal, steps, description, **kwargs):
    """One toy-text env as a domain with flat Q-learning; ``kwargs`` go to ``gymnasium.make``."""
    return DomainSpec(
        name=name,
        description=description,
        make_env=_make_env(env_id, **kwargs),
        backends=("gymnasium",),
        reference={f"optimal {optimal}": optimal},
        algos={
            "q": AlgoSpec(
                make_graph=lambda: flat_graph(n_states, 4),
                learner=Make(SMDPQLearner, alpha=ALPHA, gamma=gamma, init=init),
                exploration=epsilon_first_third,
                train=TrainConfig(
                    steps=steps, eval_every=steps // 20, eval_episodes=10, threshold=optimal
                ),
                envs_per_learner=16,
                description=f"flat Q-learning over the {n_states} states, gamma {gamma}",
            )
        },
    )


FROZEN_LAKE_4 = _domain(
    "frozenlake-4x4",
    "FrozenLake-v1",
    n_states=16,
    gamma=0.99,
    init=INIT_FROZEN_LAKE,
    optimal=1.0,
    steps=10_000,
    description="gymnasium FrozenLake-v1 4x4, not slippery (through the adapter)",
    is_slippery=False,
)
FROZEN_LAKE_8 = _domain(
    "frozenlake-8x8",
    "FrozenLake8x8-v1",
    n_states=64,
    gamma=0.99,
    init=INIT_FROZEN_LAKE,
    optimal=1.0,
    steps=40_000,
    description="gymnasium FrozenLake8x8-v1, not slippery (through the adapter)",
    is_slippery=False,
)
CLIFF_WALKING = _domain(
    "cliffwalking",
    "CliffWalking-v1",
    n_states=48,
    gamma=1.0,
    init=INIT_CLIFF_WALKING,
    optimal=-13.0,
    steps=10_000,
    description="gymnasium CliffWalking-v1, 200-step limit (through the adapter)",
    max_episode_steps=200,
)
DOMAINS = [FROZEN_LAKE_4, FROZEN_LAKE_8, CLIFF_WALKING]
