"""Settings as data: ``Make`` records, dotted names, ``sweep --grid`` and ``train --set``."""

import json
import pickle
import threading
from fractions import Fraction

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.common import config
from hrl_torch.common.checkpoint import load_checkpoint
from hrl_torch.common.config import Budget, Make, parse_settings
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.modules.schedules import Linear
from hrl_torch.runs import registry
from hrl_torch.runs.cli import main
from hrl_torch.runs.domain import setting_names, with_overrides
from hrl_torch.runs.experiment import continue_options
from hrl_torch.runs.sweep import run_sweep


def spec_of(domain="taxi", algo="maxq-q"):
    return registry.get(domain).algos[algo]


# ---------------------------------------------------------------------- records
def test_make_builds_lists_its_fields_and_replaces_by_name():
    record = Make(EpsilonGreedy, epsilon=Make(Linear, start=1.0, end=0.05, steps=Budget(0.5)))
    built = record.build(budget=101)
    assert built.epsilon == Linear(1.0, 0.05, 50)
    assert config.fields(record, "exploration") == {
        "exploration": "EpsilonGreedy",
        "exploration.epsilon": "Linear",
        "exploration.epsilon.start": 1.0,
        "exploration.epsilon.end": 0.05,
        "exploration.epsilon.steps": "Budget",
        "exploration.epsilon.steps.fraction": 0.5,
    }
    changed = config.replace(record, "epsilon.end", 0.01)
    assert changed.build(budget=101).epsilon == Linear(1.0, 0.01, 50)
    assert record.kwargs["epsilon"].kwargs["end"] == 0.05  # the original is unchanged
    assert pickle.loads(pickle.dumps(changed)) == changed
    with pytest.raises(KeyError, match="ned"):
        config.replace(record, "epsilon.ned", 0.01)
    with pytest.raises(ValueError, match="budget=steps"):
        record.build()


def test_a_share_of_the_budget_is_the_floor_division_it_replaced():
    for steps in (1, 2, 3, 59_999, 60_000, 3_000_001):
        assert Budget(Fraction(1, 3)).of(steps) == steps // 3
        assert Budget(Fraction(1, 8)).of(steps) == steps // 8
    with pytest.raises(ValueError, match="Budget.fraction"):
        Budget(-0.5)


def test_learner_fields_are_the_given_arguments_and_the_class_defaults():
    settings = spec_of().settings()
    assert settings["learner"] == "MaxQLearner"
    assert settings["learner.alpha"] == 0.5 and settings["learner.init"] == -20.0
    assert settings["learner.all_states"] is False  # a default, listed with its value
    assert "learner.graph" not in settings and "learner.n_learners" not in settings
    assert settings["exploration.epsilon.steps.fraction"] == Fraction(1, 3)


# ---------------------------------------------------------------------- with_overrides
def test_overrides_reach_the_learner_and_the_exploration_at_once():
    spec = spec_of()
    changed = with_overrides(spec, {"learner.alpha": 0.1, "exploration.epsilon.end": 0.01})
    learner = changed.make_learner(changed.make_graph(), 1)
    assert type(learner) is MaxQLearner and learner.alpha(0) == pytest.approx(0.1)
    assert learner.C.data.unique().tolist() == [-20.0]  # what was not overridden stays
    exploration = changed.make_exploration(changed.train)
    assert exploration.epsilon == Linear(1.0, 0.01, changed.train.steps // 3)
    assert spec.make_exploration(spec.train).epsilon.end == 0.05  # the spec is unchanged


def test_a_pg_field_is_a_setting():
    spec = spec_of("taxi-fuel-earlier", "hpgrl")
    assert spec.settings()["pg.alpha"] == 0.005
    changed = with_overrides(spec, {"pg.alpha": 0.01, "pg.trace_len": 300})
    learner = changed.make_learner(changed.make_graph(), 1)
    assert learner.config.alpha == 0.01 and learner.config.trace_len == 300
    with pytest.raises(ValueError, match="cannot sweep pg.alpha: choose from"):
        with_overrides(spec_of(), {"pg.alpha": 0.01})  # MAXQ-Q has no PG setting


def test_a_learner_changing_its_pg_config_leaves_the_spec_alone():
    spec = spec_of("taxi-fuel-earlier", "hpgrl")
    learner = spec.make_learner(spec.make_graph(), 1)
    learner.config.trace_len = 2  # (as tests/test_any_device.py does to force an overflow)
    assert spec.pg.trace_len == 200
    assert spec.make_learner(spec.make_graph(), 1).config.trace_len == 200


def test_any_value_is_accepted_for_a_learner_field():
    alpha = torch.tensor([0.1, 0.2])  # a per-learner value is the learner's to check
    changed = with_overrides(spec_of(), {"learner.alpha": alpha})
    assert changed.learner.kwargs["alpha"] is alpha


def test_unknown_names_are_refused_in_one_line_with_the_valid_ones():
    for name in ("learner.alfa", "exploration.epsilon.ned", "pg.alpha", "learner.graph"):
        with pytest.raises(ValueError) as err:
            with_overrides(spec_of(), {name: 0.1})
        message = str(err.value)
        assert "\n" not in message and message.startswith(f"cannot sweep {name}: choose from")
        for valid in ("steps", "learner.alpha", "learner.init", "exploration.epsilon.end"):
            assert valid in message
    assert "learner.alpha" in setting_names(spec_of())


def test_overrides_in_threads_do_not_see_each_other():
    spec, seen, errors = spec_of(), {}, []

    def work(alpha):
        try:
            for _ in range(20):
                changed = with_overrides(spec, {"learner.alpha": alpha})
                seen[alpha] = changed.make_learner(changed.make_graph(), 1).alpha(0)
                assert seen[alpha] == pytest.approx(alpha)
        except AssertionError as err:
            errors.append(err)

    threads = [threading.Thread(target=work, args=(a,)) for a in (0.1, 0.2, 0.3, 0.4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and sorted(seen) == [0.1, 0.2, 0.3, 0.4]


def test_set_parses_values_and_refuses_malformed_items():
    assert parse_settings(["learner.alpha=0.2", "steps=100", "learner.all_states=true"]) == {
        "learner.alpha": 0.2,
        "steps": 100,
        "learner.all_states": True,
    }
    for item, words in [
        ("learner.alpha", "expected NAME=VALUE"),
        ("learner..alpha=1", "expected NAME=VALUE"),
        ("learner.alpha=x", "'x' is not a finite number"),
    ]:
        with pytest.raises(ValueError, match=words):
            parse_settings([item])
    with pytest.raises(ValueError, match="given twice"):
        parse_settings(["learner.alpha=1", "learner.alpha=0.5"])


def test_a_resumed_run_keeps_its_settings():
    run = {"domain": "taxi", "algo": "maxq-q", "seeds": [0], "backend": "torch"}
    run |= {"envs_per_learner": 4, "steps": 64, "schedule_steps": 64, "eval_every": 0}
    run |= {"eval_episodes": 2, "threshold": None, "checkpoint_every": 0, "device": "cpu"}
    run |= {"collector": False, "settings": {"learner.alpha": 0.1}}
    assert continue_options("c.pt", run).settings == {"learner.alpha": 0.1}
    with pytest.raises(ValueError, match="settings .* differs"):
        continue_options("c.pt", run, settings={"learner.alpha": 0.2})
    old = {k: v for k, v in run.items() if k != "settings"}  # a checkpoint from before --set
    assert continue_options("c.pt", old).settings == {}


# ---------------------------------------------------------------------- the command line
SMALL = ["--seeds", "1", "--steps", "64", "--out"]


def train_args(out, *sets):
    argv = ["train", "taxi", "--algo", "maxq-q", *SMALL, str(out), "--envs-per-seed", "4"]
    argv += ["--eval-episodes", "2", "--no-progress", "--no-tensorboard"]
    return argv + [x for s in sets for x in ("--set", s)]


def test_a_sweep_over_a_learner_and_an_exploration_field_then_set_reaches_the_same(tmp_path):
    argv = ["sweep", "taxi", "--algo", "maxq-q", *SMALL, str(tmp_path), "--name", "s"]
    argv += ["--grid", "learner.alpha=0.1,0.5", "--grid", "exploration.epsilon.end=0.01"]
    argv += ["--grid", "envs_per_learner=4", "--grid", "eval_episodes=2", "--in-process"]
    assert main(argv) == 0  # two trials, one after the other in this process
    trials = sorted(p for p in (tmp_path / "s").iterdir() if p.is_dir())
    assert len(trials) == 2
    for trial, alpha in zip(trials, (0.1, 0.5), strict=True):
        (run_dir,) = trial.iterdir()
        hparams = json.loads((run_dir / "hparams.json").read_text())
        settings = hparams["settings"]
        assert settings["learner.alpha"] == alpha and settings["exploration.epsilon.end"] == 0.01
        assert settings["learner.init"] == -20.0 and settings["learner.gamma"] == 1.0
        assert settings["exploration.epsilon.start"] == 1.0
        assert hparams["learner"]["alpha"] == f"Constant(value={alpha})"  # as built
        assert hparams["exploration"]["epsilon"] == "Linear(start=1.0, end=0.01, steps=21)"
    # train --set with the first trial's values: the same run, table for table
    assert (
        main(train_args(tmp_path / "t", "learner.alpha=0.1", "exploration.epsilon.end=0.01")) == 0
    )
    (run_dir,) = (tmp_path / "t").iterdir()
    (swept,) = trials[0].iterdir()
    hparams = json.loads((run_dir / "hparams.json").read_text())
    assert hparams["settings"] == json.loads((swept / "hparams.json").read_text())["settings"]
    ours = load_checkpoint(run_dir / "checkpoint.pt")
    theirs = load_checkpoint(swept / "checkpoint.pt")
    assert ours["run"]["settings"] == {"learner.alpha": 0.1, "exploration.epsilon.end": 0.01}
    learned, expected = ours["trainer"]["learner"], theirs["trainer"]["learner"]
    assert learned.keys() == expected.keys()
    assert all(torch.equal(learned[k], expected[k]) for k in learned)


def test_bad_names_are_refused_in_one_line(tmp_path, capsys):
    assert main(train_args(tmp_path, "learner.alfa=0.2")) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hrl-torch: error: --set: no setting learner.alfa: choose from")
    assert "\n" not in err and "exploration.epsilon.end" in err
    assert err.endswith("; did you mean learner.alpha?")
    assert main(train_args(tmp_path, "alfa=0.2")) == 2  # (the short form: the same hint)
    assert capsys.readouterr().err.strip().endswith("did you mean learner.alpha?")
    assert main(train_args(tmp_path, "learner.alpha=-1")) == 2  # the learner's own check
    assert "alpha must be in (0, 1]" in capsys.readouterr().err
    argv = ["sweep", "taxi", "--algo", "maxq-q", "--out", str(tmp_path), "--in-process"]
    assert main([*argv, "--grid", "exploration.epsilon.ned=0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "cannot sweep exploration.epsilon.ned: choose from" in err and "\n" not in err
    assert err.endswith("did you mean exploration.epsilon.end?")
    assert not list(tmp_path.glob("*/*/hparams.json"))  # nothing ran


def test_a_pg_field_is_swept_in_process(tmp_path):
    grid = {"pg.alpha": [0.01, 0.02], "envs_per_learner": [2], "eval_episodes": [1]}
    rows = run_sweep("taxi-fuel-earlier", "hpgrl", grid, 1, out=tmp_path, steps=32, in_process=True)
    assert [r["status"] for r in rows] == ["finished", "finished"], rows
    for row in rows:
        hparams = json.loads((tmp_path / row["run_dir"] / "hparams.json").read_text())
        assert hparams["settings"]["pg.alpha"] == row["config"]["pg.alpha"]
        assert hparams["settings"]["pg.trace_len"] == 200  # the domain's, kept
