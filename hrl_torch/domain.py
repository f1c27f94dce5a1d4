"""Domains and algorithms as data: ``DomainSpec`` and ``AlgoSpec``.

A domain module (in ``agents/``) describes itself with a ``DomainSpec``: how to build its env
for a list of seeds, and per algorithm an ``AlgoSpec`` (graph, learner, exploration, default
budget). ``hrl_torch.registry`` finds domains by name; ``hrl_torch.experiment`` runs them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from hrl_torch.executor import ExecutorConfig
from hrl_torch.training import TrainConfig

if TYPE_CHECKING:
    from hrl_torch.exploration import Exploration
    from hrl_torch.graph import TaskGraph
    from hrl_torch.learners.base import Learner
    from hrl_torch.multiagent import MultiAgentConfig

__all__ = ["AlgoSpec", "DomainSpec", "EnvFactory", "algo_family"]

EnvFactory = Callable[[Sequence[int], int, str], object]


@dataclass
class AlgoSpec:
    """One algorithm on one domain.

    Attributes:
        make_graph: builds the task graph (a flat graph for flat learners).
        make_learner: ``(graph, n_learners) -> Learner``.
        make_exploration: ``(train_config) -> Exploration`` (schedules may read the budget).
        train: default training options.
        envs_per_learner: default ``E``.
        executor: executor options.
        description: one line for ``hrl-torch list``.
        multiagent: on a multi-agent domain, how the agents cooperate (``None``: selfish agents
            with their own tables); ``make_learner`` then gets the number of table sets.
        env_options: keyword arguments of the domain's ``make_env`` for this algorithm (e.g.
            one agent instead of four).
    """

    make_graph: Callable[[], TaskGraph]
    make_learner: Callable[[TaskGraph, int], Learner]
    make_exploration: Callable[[TrainConfig], Exploration]
    train: TrainConfig = field(default_factory=TrainConfig)
    envs_per_learner: int = 64
    executor: ExecutorConfig = field(default_factory=ExecutorConfig)
    description: str = ""
    multiagent: MultiAgentConfig | None = None
    env_options: dict = field(default_factory=dict)


def algo_family(**shared) -> Callable[..., AlgoSpec]:
    """A domain's ``AlgoSpec`` maker with the fields its algorithms share bound once.

    ``shared`` are ``AlgoSpec`` fields (learner, exploration, budget, ...); the maker takes
    ``(make_graph, description, multiagent=None, **env_options)``, the fields that differ.
    """

    def spec(make_graph, description: str, multiagent=None, **env_options) -> AlgoSpec:
        return AlgoSpec(
            make_graph=make_graph,
            description=description,
            multiagent=multiagent,
            env_options=env_options,
            **shared,
        )

    return spec


@dataclass
class DomainSpec:
    """A domain: its env factory, backends, algorithms and reference values.

    Attributes:
        name: CLI name (``hrl-torch train NAME``).
        make_env: ``(seeds, envs_per_learner, backend) -> env``.
        algos: algorithm name -> spec.
        backends: env backends ``make_env`` accepts (``"torch"`` first).
        eval_seed: seed of the common evaluation episodes (the same for every learner).
        reference: named reference values drawn on the plots (e.g. the optimal return).
        description: one line for ``hrl-torch list``.
        make_evaluator: ``(train_config) -> evaluator`` replacing the episodic evaluation
            (continuing tasks: ``hrl_torch.continuing.ThroughputEvaluator``); the eval env then
            has ``eval_episodes`` rows per learner.
        make_eval_env: the evaluation env's factory when it differs from the training env's
            (e.g. training restarts a continuing task now and then to see every start
            state; evaluation measures the long run without restarts). Default: ``make_env``.
    """

    name: str
    make_env: EnvFactory
    algos: dict[str, AlgoSpec]
    backends: tuple[str, ...] = ("torch",)
    eval_seed: int = 1_000_003
    reference: dict[str, float] = field(default_factory=dict)
    description: str = ""
    make_evaluator: Callable[[TrainConfig], object] | None = None
    make_eval_env: EnvFactory | None = None
