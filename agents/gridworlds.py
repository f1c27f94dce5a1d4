"""What the small gridworld domains share: env factory, optimal return, algorithm budget.

Used by ``agents.four_rooms`` and ``agents.key_door``.
"""

from __future__ import annotations

from agents.taxi import epsilon_first_third
from envs.grid import TableEnv, optimal_values
from hrl_torch.experiment import AlgoSpec
from hrl_torch.trainer import TrainConfig

EVAL_SEED = 1_000_003
EVAL_EPISODES = 100
STEPS = 100_000


def env_factory(env_class: type[TableEnv]):
    """``make_env(seeds, envs_per_learner, backend)`` of a ``DomainSpec`` (torch only)."""

    def make_env(seeds, envs_per_learner: int, backend: str = "torch") -> TableEnv:
        if backend != "torch":
            raise ValueError(f"unknown backend {backend!r}")
        return env_class(seeds, envs_per_learner)

    return make_env


def optimal_eval_return(
    env_class: type[TableEnv], seed: int = EVAL_SEED, episodes: int = EVAL_EPISODES
) -> float:
    """The optimal policy's mean return on the evaluation episodes (shortest paths)."""
    value = optimal_values(*env_class.transition_tables()[:3])
    return float(value[env_class([seed], episodes).reset()["observation"]].mean())


def grid_algo(make_graph, make_learner, description: str, threshold: float, **options) -> AlgoSpec:
    """One algorithm of a gridworld.

    100,000 steps, 64 envs per seed, epsilon 1 -> 0.05 over the first third, 20 evaluations.
    """
    return AlgoSpec(
        make_graph=make_graph,
        make_learner=make_learner,
        make_exploration=epsilon_first_third,
        train=TrainConfig(steps=STEPS, eval_every=STEPS // 20, threshold=threshold),
        envs_per_learner=64,
        description=description,
        **options,
    )
