"""Algorithms registered once (``hrl_torch.runs.algorithms``): one learner per ``--algo`` name on
every domain, a domain's own settings on top, and a plugin's learner on every compatible domain."""

import json
import sys
from pathlib import Path

import pytest

import agents  # noqa: F401
from hrl_torch.common.config import Make
from hrl_torch.learners import MaxQLearner, SMDPQLearner
from hrl_torch.runs import algorithms, registry
from hrl_torch.runs.algorithms import Algorithm, Tasks
from hrl_torch.runs.domain import AlgoSpec, DomainSpec
from hrl_torch.training.config import TrainConfig

ROOT = Path(__file__).resolve().parents[1]


def test_an_algo_name_is_one_learner_on_every_domain():
    registered = algorithms.algorithms()
    seen = {}
    for name in registry.names():
        for algo, spec in registry.get(name).algos.items():
            if algo in registered and isinstance(spec.learner, Make):
                assert spec.learner.target is registered[algo].learner, (name, algo)
                seen.setdefault(algo, set()).add(name)
    assert {"taxi", "four-rooms", "key-door"} <= seen["smdp-q"]
    assert {"taxi", "four-rooms", "key-door"} <= seen["maxq-q"] & seen["q"]


def test_a_domain_sets_only_what_it_must_and_the_family_the_rest():
    spec = registry.get("four-rooms").algos["smdp-q"]
    assert spec.learner.target is SMDPQLearner
    assert spec.learner.kwargs["gamma"] == 1.0  # the family's default
    maxq = registry.get("four-rooms").algos["maxq-q"]
    assert maxq.learner.kwargs["all_states"] is True  # four-rooms' own, for maxq-q alone
    assert "all_states" not in spec.learner.kwargs
    assert spec.train == maxq.train and spec.envs_per_learner == maxq.envs_per_learner == 64


def test_a_domain_algorithm_under_a_registered_name_must_use_its_learner():
    with pytest.raises(ValueError, match="registered as MaxQLearner"):
        DomainSpec(
            "bad",
            make_env=lambda *a: None,
            algos={"maxq-q": AlgoSpec(lambda: None, Make(SMDPQLearner), Make(dict))},
        )


def test_a_later_registered_algorithm_reaches_the_domains_registered_before(monkeypatch):
    monkeypatch.setattr(algorithms, "_ALGORITHMS", dict(algorithms.algorithms()))
    tasks = Tasks(
        graphs={"hierarchy": lambda: None},
        offers=frozenset({"tabular", "single-agent", "episodic"}),
        exploration=Make(dict),
        train=TrainConfig(steps=10),
    )
    spec = DomainSpec("toy", make_env=lambda *a: None, tasks=tasks)
    assert "q" not in spec.algos  # no flat graph offered
    algorithms.register_algorithm(Algorithm("maxq-q-2", MaxQLearner, settings={"alpha": 0.1}))
    later = spec.with_registered_algorithms()
    assert later.algos["maxq-q-2"].learner == Make(MaxQLearner, alpha=0.1)
    assert later.algos["maxq-q"] == spec.algos["maxq-q"]
    with pytest.raises(ValueError, match="registered already"):
        algorithms.register_algorithm(Algorithm("maxq-q-2", SMDPQLearner))


def test_a_plugin_learner_trains_from_the_cli_on_taxi_and_four_rooms(tmp_path, monkeypatch, capsys):
    # in this process (a fresh interpreter per command costs ~10 s here); the plugin's
    # registration is undone afterwards
    from hrl_torch.runs import cli

    monkeypatch.setattr(algorithms, "_ALGORITHMS", dict(algorithms.algorithms()))
    monkeypatch.syspath_prepend(str(ROOT / "tests" / "plugins"))
    monkeypatch.delitem(sys.modules, "expected_sarsa_algorithm", raising=False)
    monkeypatch.chdir(tmp_path)
    plugin = ["--domain-module", "expected_sarsa_algorithm"]
    assert cli.main([*plugin, "list"]) == 0
    listing = capsys.readouterr().out
    for domain in ("taxi", "four-rooms"):
        assert "expected-sarsa" in listing.split(domain, 1)[1]
        code = cli.main(
            [
                *plugin,
                "train",
                domain,
                "--algo",
                "expected-sarsa",
                "--seeds",
                "1",
                "--steps",
                "600",
                "--envs-per-seed",
                "4",
                "--eval-episodes",
                "3",
                "--out",
                "runs",
                "--no-progress",
            ]
        )
        assert code == 0, capsys.readouterr().err[-2000:]
        (run,) = (tmp_path / "runs").glob(f"{domain}__expected-sarsa__*")
        summary = json.loads((run / "summary.json").read_text())
        assert summary["algo"] == "expected-sarsa"


def test_the_average_reward_domains_offer_the_continuing_families_and_a_later_one(monkeypatch):
    from hrl_torch.learners import RVIQLearner

    small, agv = registry.get("small-agv"), registry.get("agv")
    assert {"har", "rar", "hdr", "hh", "rvi-q"} <= set(small.algos)
    assert {"har", "rar", "hdr", "rvi-q"} <= set(agv.algos) and "hh" not in agv.algos  # without
    assert "maxq-q" in small.algos and "maxq-q" in small.own_algos  # the domain's own, discounted
    monkeypatch.setattr(algorithms, "_ALGORITHMS", dict(algorithms.algorithms()))
    algorithms.register_algorithm(
        Algorithm("rvi-q-2", RVIQLearner, "flat", frozenset({"tabular", "continuing"}))
    )
    for domain in (small, agv, registry.get("agv-ct")):
        assert "rvi-q-2" in domain.with_registered_algorithms().algos, domain.name
