"""Domains and algorithms as data: ``DomainSpec`` and ``AlgoSpec``.

A domain module (in ``agents/``) describes itself with a ``DomainSpec``: how to build its env
for a list of seeds, and per algorithm an ``AlgoSpec`` (graph, learner, exploration, default
budget), the learner and exploration as data (``hrl_torch.common.config.Make``) whose fields
``with_overrides`` changes by dotted name. ``hrl_torch.runs.registry`` finds domains by name;
``hrl_torch.runs.experiment`` runs them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import functools
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, is_dataclass
from typing import TYPE_CHECKING

from hrl_torch.common import config
from hrl_torch.common.config import Make
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.hierarchy.subtask import GraphError
from hrl_torch.runs import algorithms
from hrl_torch.training.config import TrainConfig

if TYPE_CHECKING:
    from hrl_torch.hierarchy.graph import TaskGraph
    from hrl_torch.learners.base import Learner
    from hrl_torch.modules.exploration import Exploration
    from hrl_torch.multiagent.cooperative import MultiAgentConfig

__all__ = [
    "TRAIN_KEYS",
    "AlgoSpec",
    "DomainSpec",
    "EnvFactory",
    "SettingError",
    "algo_family",
    "setting_names",
    "with_overrides",
]

EnvFactory = Callable[[Sequence[int], int, str], object]


@dataclass
class AlgoSpec:
    """One algorithm on one domain.

    Attributes:
        make_graph: builds the task graph (a flat graph for flat learners).
        learner: the learner as data, ``Make(MaxQLearner, alpha=0.5, init=-20.0)``, built as
            ``learner.build(graph, n_learners)`` (with ``pg``: ``(graph, n_learners, pg)``).
            A plain function ``(graph, n_learners) -> Learner`` also works (a user's plugin),
            but then no learner field can be swept or ``--set``.
        exploration: the exploration as data, ``Make(EpsilonGreedy, epsilon=Make(Linear,
            start=1.0, end=0.05, steps=Budget(Fraction(1, 3))))``; a ``Budget`` is a share of
            the run's training budget. A function ``(train_config) -> Exploration`` also works.
        pg: a policy-gradient learner's option group (``PGConfig``), handed to the learner as
            its third positional argument; ``None`` for other learners.
        train: default training options.
        envs_per_learner: default ``E``.
        executor: executor options.
        description: one line for ``hrl-torch list``.
        multiagent: on a multi-agent domain, how the agents cooperate (``None``: selfish agents
            with their own tables); the learner then gets the number of table sets.
        env_options: keyword arguments of the domain's ``make_env`` for this algorithm (e.g.
            one agent instead of four).

    Every field of ``learner``, ``exploration`` and ``pg`` has a dotted name
    (``learner.alpha``, ``exploration.epsilon.end``, ``pg.alpha``): ``settings`` lists them,
    ``with_overrides`` changes them (the names ``hrl-torch sweep --grid`` and ``--set`` take).
    """

    make_graph: Callable[[], TaskGraph]
    learner: Make | Callable[[TaskGraph, int], Learner]
    exploration: Make | Callable[[TrainConfig], Exploration]
    pg: object | None = None
    train: TrainConfig = field(default_factory=TrainConfig)
    envs_per_learner: int = 64
    executor: ExecutorConfig = field(default_factory=ExecutorConfig)
    description: str = ""
    multiagent: MultiAgentConfig | None = None
    env_options: dict = field(default_factory=dict)

    def make_learner(self, graph: TaskGraph, n_learners: int) -> Learner:
        """The learner for ``n_learners`` table sets on ``graph`` (``SettingError``)."""
        # (the learner gets its own copy of ``pg``: a spec's setting is never shared or changed)
        pg = None if self.pg is None else dataclasses.replace(self.pg)
        positional = (graph, n_learners) if pg is None else (graph, n_learners, pg)
        with refused_settings():
            if isinstance(self.learner, Make):
                return self.learner.build(*positional)
            return self.learner(*positional)

    def make_exploration(self, train: TrainConfig) -> Exploration:
        """The exploration; its ``Budget`` shares read ``train.steps`` (``SettingError``)."""
        with refused_settings():
            if isinstance(self.exploration, Make):
                return self.exploration.build(budget=train.steps)
            return self.exploration(train)

    def settings(self, classes: bool = True) -> dict:
        """Every field of the learner, exploration and PG setting by dotted name, as used.

        With ``classes`` a record's own name holds its class: ``{"learner": "MaxQLearner",
        "learner.alpha": 0.5, ..., "exploration.epsilon.end": 0.05, ...}``.
        """
        out = {}
        for part, value in self._parts().items():
            if isinstance(value, Make) or is_dataclass(value):
                out.update(config.fields(value, part, self._positional(part), classes))
        return out

    def _parts(self) -> dict:
        return {"learner": self.learner, "exploration": self.exploration, "pg": self.pg}

    def _positional(self, part: str) -> int:
        """Positional values the part's build gets (those parameters are not fields)."""
        return {"learner": 2 if self.pg is None else 3}.get(part, 0)


class SettingError(ValueError):
    """A value a learner's or exploration's class refuses when it is built, in one line.

    ``AlgoSpec.make_learner`` and ``make_exploration`` raise it, so a bad ``--set`` value is
    refused where the value is used, before a run writes anything (no separate check build).
    """


@contextlib.contextmanager
def refused_settings():
    """``TypeError`` / ``ValueError`` of a build as ``SettingError`` (a graph's own: as it is)."""
    try:
        yield
    except (GraphError, SettingError):
        raise
    except (TypeError, ValueError) as err:
        raise SettingError(" ".join(str(err).split())) from err


#: the numeric ``TrainConfig`` fields ``with_overrides`` sets by name
TRAIN_KEYS = (
    "steps",
    "eval_every",
    "eval_episodes",
    "eval_max_steps",
    "log_every",
    "threshold",
    "checkpoint_every",
)


def setting_names(spec: AlgoSpec) -> list[str]:
    """The names of the values ``with_overrides`` sets on ``spec``.

    It also takes a record's own name (``exploration.epsilon``) to replace the whole record.
    """
    return [*TRAIN_KEYS, "envs_per_learner", *spec.settings(classes=False)]


def with_overrides(spec: AlgoSpec, overrides: dict, unknown: str = "cannot sweep") -> AlgoSpec:
    """``spec`` with settings changed by name; ``spec`` itself is unchanged (thread-safe).

    Names: the ``TrainConfig`` fields of ``TRAIN_KEYS`` and ``envs_per_learner`` (whole
    numbers; ``threshold`` any number), and every dotted name ``spec.settings()`` lists
    (``learner.alpha``, ``exploration.epsilon.end``, ``pg.alpha``); a bare learner argument
    (``alpha``) means ``learner.alpha``. Learner, exploration and PG values are not checked
    here (a tensor per learner is fine): their classes check them when built.

    Raises:
        ValueError: one line: an unknown name after the words ``unknown`` (``"cannot sweep"``
            for a sweep's grid, ``"no setting"`` for ``train --set``), with the names there are
            and the nearest ones, or a bad type for a ``TrainConfig`` field or
            ``envs_per_learner``.
    """
    for name, value in overrides.items():
        spec = _with(spec, _full_name(spec, name, unknown), value)
    return spec


def _nearest(spec: AlgoSpec, name: str) -> list[str]:
    """The settings nearest to ``name`` (difflib's ratio, 0.6 at least; ties all named).

    A learner argument's short form (``alpha`` for ``learner.alpha``) is compared too.
    """
    names = setting_names(spec)
    short = {n.removeprefix("learner."): n for n in names if n.startswith("learner.")}
    ratio = {n: difflib.SequenceMatcher(None, name, n).ratio() for n in [*names, *short]}
    best = max(ratio.values(), default=0.0)
    if best < 0.6:
        return []
    return list(dict.fromkeys(short.get(n, n) for n, r in ratio.items() if r >= best - 1e-9))


def _full_name(spec: AlgoSpec, name: str, unknown: str = "cannot sweep") -> str:
    if name in (*TRAIN_KEYS, "envs_per_learner"):
        return name
    names = spec.settings()
    if name in names and "." in name:
        return name
    if f"learner.{name}" in names:  # the short form of a learner argument
        return f"learner.{name}"
    learner = names.get("learner", "a function (no fields)")
    near = _nearest(spec, name)
    hint = f"; did you mean {' or '.join(near)}?" if near else ""
    raise ValueError(
        f"{unknown} {name}: choose from {', '.join(setting_names(spec))} (learner: {learner})"
        + hint
    )


def _with(spec: AlgoSpec, name: str, value) -> AlgoSpec:
    """``spec`` with one known name set."""
    if name in (*TRAIN_KEYS, "envs_per_learner"):
        kinds = (int, float) if name == "threshold" else int
        if isinstance(value, bool) or not isinstance(value, kinds):
            what = "a number" if name == "threshold" else "a whole number"
            raise ValueError(f"{name} must be {what}, got {value!r}")
        low = 1 if name in ("steps", "log_every", "eval_max_steps", "envs_per_learner") else 0
        if name != "threshold" and value < low:
            raise ValueError(f"{name} must be a whole number >= {low}, got {value!r}")
        if name == "envs_per_learner":
            return dataclasses.replace(spec, envs_per_learner=value)
        return dataclasses.replace(spec, train=dataclasses.replace(spec.train, **{name: value}))
    part, _, path = name.partition(".")
    old = spec._parts()[part]
    new = config.replace(old, path, value, spec._positional(part))
    return dataclasses.replace(spec, **{part: new})


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


#: 0.1's ``AlgoSpec`` fields in their order (``make_learner``, ``make_exploration``, no ``pg``)
ALGO_SPEC_0_1 = (
    "make_graph",
    "make_learner",
    "make_exploration",
    "train",
    "envs_per_learner",
    "executor",
    "description",
    "multiagent",
    "env_options",
)
_RENAMED_0_1 = {"make_learner": "learner", "make_exploration": "exploration"}


def algo_spec_arguments(args: tuple, kwargs: dict) -> tuple[tuple, dict]:
    """0.1's ``AlgoSpec`` arguments as today's, with a DeprecationWarning; others unchanged.

    0.1 took ``(make_graph, make_learner, make_exploration, train, ...)``; 0.2 renamed the two
    makers ``learner`` and ``exploration`` and put ``pg`` before ``train``. A 0.1 call is one
    whose fourth positional argument is a ``TrainConfig`` or that names an old field.
    """
    old_order = len(args) > 3 and isinstance(args[3], TrainConfig)
    old_names = sorted(set(kwargs) & set(_RENAMED_0_1))
    if not (old_order or old_names):
        return args, kwargs
    warnings.warn(
        "AlgoSpec(make_graph, make_learner, make_exploration, train, ...) is 0.1's: name the "
        "fields learner= and exploration= (pg= comes before train=); 0.1's form goes in 0.3.0",
        DeprecationWarning,
        stacklevel=3,
    )
    if len(args) > len(ALGO_SPEC_0_1):
        raise TypeError(f"AlgoSpec takes at most {len(ALGO_SPEC_0_1)} positional arguments")
    given = {**dict(zip(ALGO_SPEC_0_1, args, strict=False)), **kwargs} if old_order else kwargs
    return (), {_RENAMED_0_1.get(key, key): value for key, value in given.items()}


_dataclass_init = AlgoSpec.__init__


@functools.wraps(_dataclass_init)  # (its signature is the dataclass's)
def _init_accepting_0_1(self, *args, **kwargs) -> None:
    args, kwargs = algo_spec_arguments(args, kwargs)
    _dataclass_init(self, *args, **kwargs)


AlgoSpec.__init__ = _init_accepting_0_1


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
            (continuing tasks: ``hrl_torch.training.continuing.ThroughputEvaluator``); the eval env
            then has ``eval_episodes`` rows per learner.
        make_eval_env: the evaluation env's factory when it differs from the training env's
            (e.g. training restarts a continuing task now and then to see every start
            state; evaluation measures the long run without restarts). Default: ``make_env``.
        tasks: what the domain offers the registered algorithms (``runs.algorithms.Tasks``):
            ``algos`` then also holds every compatible registered algorithm's spec, and the
            ones given in ``algos`` are the domain's own (a name that is a registered
            algorithm's must use its learner: ``--algo NAME`` is one family everywhere).
    """

    name: str
    make_env: EnvFactory
    algos: dict[str, AlgoSpec] = field(default_factory=dict)
    backends: tuple[str, ...] = ("torch",)
    eval_seed: int = 1_000_003
    reference: dict[str, float] = field(default_factory=dict)
    description: str = ""
    make_evaluator: Callable[[TrainConfig], object] | None = None
    make_eval_env: EnvFactory | None = None
    tasks: algorithms.Tasks | None = None
    own_algos: frozenset[str] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        registered = algorithms.algorithms()
        for name, spec in self.algos.items():
            family = registered.get(name)
            if family is not None and isinstance(spec.learner, Make):
                if spec.learner.target is not family.learner:
                    raise ValueError(
                        f"domain {self.name!r}: algorithm {name!r} is registered as "
                        f"{family.learner.__name__}, not {spec.learner.target.__name__}; "
                        "give this learner another name"
                    )
        self.own_algos = frozenset(getattr(self, "own_algos", None) or self.algos)
        if self.tasks is not None:
            derived = algorithms.fields_for(self.tasks)
            own = {name: self.algos[name] for name in self.own_algos}
            self.algos = {**{n: AlgoSpec(**f) for n, f in derived.items()}, **own}

    def with_registered_algorithms(self) -> DomainSpec:
        """This domain with the algorithms registered since it was made (plugins) added."""
        if self.tasks is None or not any(
            name not in self.algos and self.tasks.runs(a)
            for name, a in algorithms.algorithms().items()
        ):
            return self
        return dataclasses.replace(self, algos={n: self.algos[n] for n in self.own_algos})
