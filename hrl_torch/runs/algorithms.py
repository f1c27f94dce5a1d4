"""Algorithms registered once, for every domain that offers what they need.

BenchMARL's algorithm x task registry is the model. An ``Algorithm`` names a learner family,
the graph it runs on (the domain's ``"hierarchy"`` or ``"flat"`` graph), what it needs of a task
and its default settings. A domain describes itself with ``Tasks``: its graphs, what it offers
(``"tabular"``, ``"single-agent"``, ``"episodic"`` or ``"continuing"``, ...), the budget, rows
and exploration every algorithm there shares, and only the settings it must change: for all of
them (``learner``) or for one (``per_algorithm``). ``DomainSpec(tasks=...)`` then holds the
``AlgoSpec`` of every registered algorithm the domain can run, so ``--algo NAME`` means one
learner family everywhere and a plugin's ``register_algorithm`` reaches every compatible domain.

    register_algorithm(Algorithm("expected-sarsa", ExpectedSarsa, settings={"alpha": 0.5}))
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from hrl_torch import learners
from hrl_torch.common.config import Make

#: what a domain can offer and an algorithm can need
CAPABILITIES = frozenset(
    {"tabular", "single-agent", "multi-agent", "episodic", "continuing", "policy-gradient"}
)
#: where an algorithm's settings for one domain come from, in order (later wins)
SETTING_ORDER = ("the algorithm's defaults", "Tasks.learner", "Tasks.per_algorithm[name]")


@dataclass(frozen=True)
class Algorithm:
    """One learner family, registered once.

    Attributes:
        name: the ``--algo`` name, the same on every domain.
        learner: the learner class, built as ``learner(graph, n_learners, **settings)``.
        graph: the domain graph it runs on: ``"hierarchy"`` or ``"flat"``.
        needs: what the domain must offer (``CAPABILITIES``).
        settings: its default learner settings; a domain changes only what it must.
        description: one line for ``hrl-torch list`` (a domain may give its own).
    """

    name: str
    learner: Callable
    graph: str = "hierarchy"
    needs: frozenset[str] = frozenset({"tabular", "single-agent", "episodic"})
    settings: Mapping[str, object] = field(default_factory=dict)
    description: str = ""

    def __post_init__(self) -> None:
        unknown = set(self.needs) - CAPABILITIES
        if unknown:
            raise ValueError(f"algorithm {self.name!r} needs unknown {sorted(unknown)}")
        if self.graph not in ("hierarchy", "flat"):
            raise ValueError(f"algorithm {self.name!r}: graph must be 'hierarchy' or 'flat'")


@dataclass(frozen=True)
class Tasks:
    """What a domain offers every registered algorithm.

    Attributes:
        graphs: ``"hierarchy"`` and/or ``"flat"`` -> a maker of that task graph.
        offers: what the domain is (``CAPABILITIES``).
        exploration: the exploration every algorithm here starts from (``AlgoSpec.exploration``).
        train: the training options every algorithm here starts from.
        envs_per_learner: default ``E``.
        learner: learner settings this domain sets for every algorithm (e.g. ``gamma``,
            ``init``), over the algorithms' defaults.
        per_algorithm: algorithm name -> what this domain changes for it alone: learner
            settings under ``"learner"``, any other ``AlgoSpec`` field by its name
            (``train``, ``executor``, ``description``, ...).
        only: if given, the algorithm names offered (others are left out even if compatible).
    """

    graphs: Mapping[str, Callable]
    offers: frozenset[str]
    exploration: object
    train: object
    envs_per_learner: int = 64
    learner: Mapping[str, object] = field(default_factory=dict)
    per_algorithm: Mapping[str, Mapping[str, object]] = field(default_factory=dict)
    only: frozenset[str] | None = None

    def runs(self, algorithm: Algorithm) -> bool:
        """Whether ``algorithm`` can run on this domain."""
        return (
            set(algorithm.needs) <= set(self.offers)
            and algorithm.graph in self.graphs
            and (self.only is None or algorithm.name in self.only)
        )


_ALGORITHMS: dict[str, Algorithm] = {}


def register_algorithm(algorithm: Algorithm) -> None:
    """Register ``algorithm`` for every domain that offers what it needs.

    Raises:
        ValueError: another algorithm is registered under the same name.
    """
    known = _ALGORITHMS.get(algorithm.name)
    if known is not None and known != algorithm:
        raise ValueError(f"algorithm {algorithm.name!r} is registered already ({known.learner})")
    _ALGORITHMS[algorithm.name] = algorithm


def algorithms() -> dict[str, Algorithm]:
    """The registered algorithms by name."""
    return dict(_ALGORITHMS)


def spec_fields(algorithm: Algorithm, tasks: Tasks) -> dict | None:
    """``algorithm``'s ``AlgoSpec`` fields on a domain offering ``tasks`` (``None``: it cannot run).

    Learner settings: the algorithm's defaults, then ``tasks.learner``, then the domain's
    ``per_algorithm`` entry (``SETTING_ORDER``).
    """
    if not tasks.runs(algorithm):
        return None
    own = dict(tasks.per_algorithm.get(algorithm.name, {}))
    settings = {**algorithm.settings, **tasks.learner, **own.pop("learner", {})}
    return {
        "make_graph": tasks.graphs[algorithm.graph],
        "learner": Make(algorithm.learner, **settings),
        "exploration": own.pop("exploration", tasks.exploration),
        "train": own.pop("train", tasks.train),
        "envs_per_learner": own.pop("envs_per_learner", tasks.envs_per_learner),
        "description": own.pop("description", algorithm.description),
        **own,
    }


def fields_for(tasks: Tasks) -> dict[str, dict]:
    """Every registered algorithm's ``AlgoSpec`` fields on a domain offering ``tasks``."""
    unknown = set(tasks.per_algorithm) - set(_ALGORITHMS)
    if unknown:
        raise ValueError(f"settings for unregistered algorithms {sorted(unknown)}")
    found = {name: spec_fields(a, tasks) for name, a in _ALGORITHMS.items()}
    return {name: fields for name, fields in found.items() if fields is not None}


# ---------------------------------------------------------------------- the built-in families
_EPISODIC = frozenset({"tabular", "single-agent", "episodic"})
_CONTINUING = frozenset({"tabular", "single-agent", "continuing"})
#: name, learner, graph, needs, default settings, description
_BUILT_IN = (
    ("maxq-q", learners.MaxQLearner, "hierarchy", _EPISODIC, {"alpha": 0.5, "gamma": 1.0},
     "MAXQ-Q (Dietterich 2000) on the task graph"),
    ("smdp-q", learners.SMDPQLearner, "hierarchy", _EPISODIC, {"alpha": 0.5, "gamma": 1.0},
     "SMDP Q-learning at every subtask (HSMQ) on the task graph"),
    ("q", learners.SMDPQLearner, "flat", _EPISODIC, {"alpha": 0.5, "gamma": 1.0},
     "flat Q-learning over the states"),
    ("har", learners.HARLearner, "hierarchy", _CONTINUING, {"alpha": 0.1},
     "hierarchically optimal average reward RL (Algorithm 1)"),
    ("rar", learners.RARLearner, "hierarchy", _CONTINUING, {"alpha": 0.1},
     "recursively optimal average reward RL (Algorithm 2)"),
    ("hdr", learners.HDRLearner, "hierarchy", _CONTINUING, {"alpha": 0.1, "gamma": 0.95},
     "hierarchically optimal discounted RL (MAXQ-Q + external completions)"),
    ("hh", learners.HHLearner, "hierarchy", _CONTINUING, {},
     "HH-learning (Seri and Tadepalli 2002), model-based"),
    ("rvi-q", learners.RVIQLearner, "flat", _CONTINUING, {"alpha": 0.1},
     "flat RVI Q-learning (Abounadi et al. 2001)"),
)
for _name, _learner, _graph, _needs, _settings, _description in _BUILT_IN:
    register_algorithm(Algorithm(_name, _learner, _graph, _needs, _settings, _description))
