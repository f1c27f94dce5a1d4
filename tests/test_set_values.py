"""``--set`` values checked against their field's type and range, and domains registered under
their spec's own name, each refused in one line before anything is written."""

from dataclasses import replace

import pytest

from hrl_torch.runs import registry
from hrl_torch.runs.cli import main

SET_CASES = {
    "exploration.epsilon.end=1.5": "--set: EpsilonGreedy: epsilon.end must be in [0, 1], got 1.5",
    "exploration.epsilon.start=-0.1": (
        "--set: EpsilonGreedy: epsilon.start must be in [0, 1], got -0.1"
    ),
    "learner.all_states=7": "--set: all_states is a flag (now False): give true or false, got 7",
    "learner.alpha=true": "--set: alpha is a number (now 0.5), got True",
    "envs_per_learner=0": "--set: envs_per_learner must be a whole number >= 1, got 0",
    "steps=0": "--set: steps must be a whole number >= 1, got 0",
    "eval_episodes=-2": "--set: eval_episodes must be a whole number >= 0, got -2",
}


@pytest.mark.parametrize("item", list(SET_CASES))
def test_a_set_value_outside_its_fields_type_or_range_is_one_line(item, tmp_path, capsys):
    argv = ["train", "taxi", "--algo", "maxq-q", "--set", item, "--out", str(tmp_path / "runs")]
    assert main([*argv, "--no-progress", "--steps", "64", "--seeds", "1"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == f"hrl-torch: error: {SET_CASES[item]}", line
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_a_domain_registered_under_another_name_than_its_specs_is_refused(monkeypatch, tmp_path):
    from agents.taxi import DOMAIN

    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    with pytest.raises(ValueError, match="'cab' .* is a DomainSpec named 'taxi'.* register it as"):
        registry.register("cab", DOMAIN, source="module mine")
    # an entry point (imported on first use) naming a spec of another name: refused when loaded
    (tmp_path / "renamed_domain.py").write_text(
        "from dataclasses import replace\n"
        "from agents.taxi import DOMAIN as TAXI\n"
        "SPEC = replace(TAXI, name='taxi-renamed')\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.register("taxi-two", "renamed_domain:SPEC", source="plugin mine")
    with pytest.raises(ValueError, match="'taxi-two' .* is a DomainSpec named 'taxi-renamed'"):
        registry.get("taxi-two")
    registry.register("taxi-same", replace(DOMAIN, name="taxi-same"))  # its own name: fine
    assert registry.get("taxi-same").name == "taxi-same"
