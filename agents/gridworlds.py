"""What the small gridworld domains share: env factory, optimal return, algorithm budget.

Used by ``agents.four_rooms`` and ``agents.key_door``.
"""

from __future__ import annotations

from agents.taxi import epsilon_first_third, flat_graph
from envs.grid import TableEnv, optimal_values
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.runs.algorithms import Tasks
from hrl_torch.runs.domain import DomainSpec
from hrl_torch.training.config import TrainConfig

EVAL_SEED = 1_000_003
EVAL_EPISODES = 100
STEPS = 100_000
ALPHA = 0.5  # step size 0.5 beat 0.1 on both gridworlds (docs/defaults.md)
VISITED = 32  # states of a child kept for all-states updating


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


def gridworld_domain(
    name: str,
    description: str,
    env_class: type[TableEnv],
    hierarchy,
    hierarchy_text: str,
    optimal: float,
    threshold: float,
    maxq_init: float,
    q_init: float,
) -> DomainSpec:
    """A gridworld domain with its measured initial values.

    Every registered tabular algorithm; MAXQ-Q with all-states updating on ``hierarchy``, flat
    Q-learning over the env's states from their own measured initial value ``q_init``.
    """
    n_states, n_actions = env_class.transition_tables()[0].shape
    return DomainSpec(
        name=name,
        description=description,
        make_env=env_factory(env_class),
        eval_seed=EVAL_SEED,
        reference={f"optimal {optimal:.2f}": optimal, f"threshold {threshold:.2f}": threshold},
        # every registered tabular algorithm: 100,000 steps, 64 envs per seed, epsilon 1 -> 0.05
        # over the first third, 20 evaluations
        tasks=Tasks(
            graphs={
                "hierarchy": hierarchy,
                "flat": lambda: env_class.tabulate(flat_graph(n_states, n_actions)),
            },
            offers=frozenset({"tabular", "single-agent", "episodic"}),
            exploration=epsilon_first_third,
            train=TrainConfig(steps=STEPS, eval_every=STEPS // 20, threshold=threshold),
            envs_per_learner=64,
            learner={"alpha": ALPHA, "init": maxq_init},
            per_algorithm={
                "maxq-q": {
                    "learner": {"all_states": True},
                    "executor": ExecutorConfig(record_visited=VISITED),
                    "description": f"MAXQ-Q (all-states updating) on {hierarchy_text}",
                },
                "smdp-q": {"description": f"SMDP Q-learning at every subtask of {hierarchy_text}"},
                "q": {
                    "learner": {"init": q_init},
                    "description": f"flat Q-learning over the {n_states} states",
                },
            },
        ),
    )
