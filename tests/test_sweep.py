"""Sweeps: the grid, how values reach a run, the sweep folder, and a local Ray sweep."""

import argparse
import json
import sys

import pytest

import agents  # noqa: F401  (registers the domains)
from hrl_torch.learners import MaxQLearner, SMDPQLearner
from hrl_torch.runs import registry
from hrl_torch.runs.cli_parser import add_sweep_parser
from hrl_torch.runs.domain import with_overrides
from hrl_torch.runs.sweep import (
    INSTALL_HINT,
    configurations,
    default_metric,
    label,
    parse_grid,
    run_sweep,
    run_sweep_command,
)


def taxi_spec(algo="maxq-q"):
    return registry.get("taxi").algos[algo]


def build(spec, n=2):
    return spec.make_learner(spec.make_graph(), n)


# ---------------------------------------------------------------------- parse_grid
def test_parse_grid_numbers_and_booleans():
    grid = parse_grid(["alpha=0.1,0.5", "init=-20,0", "all_states=true,False", "gamma=1e-1"])
    assert grid == {
        "alpha": [0.1, 0.5],
        "init": [-20, 0],
        "all_states": [True, False],
        "gamma": [0.1],
    }
    assert [type(v) for v in grid["init"]] == [int, int]
    assert configurations(grid)[:2] == [
        {"alpha": 0.1, "init": -20, "all_states": True, "gamma": 0.1},
        {"alpha": 0.1, "init": -20, "all_states": False, "gamma": 0.1},
    ]
    assert len(configurations(grid)) == 8
    assert label({"alpha": 0.1, "init": -20}) == "alpha=0.1_init=-20"


@pytest.mark.parametrize(
    "item, words",
    [
        ("alpha", "expected NAME=V1,V2"),
        ("=0.1", "expected NAME=V1,V2"),
        ("al pha=1", "expected NAME=V1,V2"),
        ("alpha=", "an empty value"),
        ("alpha=0.1,,0.5", "an empty value"),
        ("alpha=0.1,x", "'x' is not a finite number"),
        ("alpha=nan", "'nan' is not a finite number"),
        ("alpha=inf", "'inf' is not a finite number"),
        ("alpha=1,1", "a value is repeated"),
    ],
)
def test_parse_grid_names_the_bad_item(item, words):
    with pytest.raises(ValueError, match="grid item") as err:
        parse_grid(["init=0", item])
    assert repr(item) in str(err.value) and words in str(err.value)


def test_parse_grid_refuses_a_name_given_twice():
    with pytest.raises(ValueError, match="alpha is given twice"):
        parse_grid(["alpha=0.1", "alpha=0.5"])


# ---------------------------------------------------------------------- with_overrides
def test_learner_argument_given_positionally_is_replaced_and_the_others_kept():
    # taxi builds MaxQLearner(g, p, 0.5, 1.0, init=-20): alpha is positional
    learner = build(with_overrides(taxi_spec(), {"alpha": 0.1}))
    assert type(learner) is MaxQLearner
    assert learner.alpha(0) == pytest.approx(0.1)
    assert learner.gamma == 1.0
    assert learner.C.data.unique().tolist() == [-20.0]  # the domain's init is kept
    learner = build(with_overrides(taxi_spec(), {"init": -3, "gamma": 0.9}))
    assert learner.alpha(0) == pytest.approx(0.5)
    assert learner.gamma == pytest.approx(0.9)
    assert learner.C.data.unique().tolist() == [-3.0]


def test_overrides_leave_the_class_and_the_original_spec_alone():
    spec = taxi_spec()
    changed = with_overrides(spec, {"alpha": 0.1})
    build(changed)
    assert build(spec).alpha(0) == pytest.approx(0.5)
    direct = MaxQLearner(spec.make_graph(), 1)  # the class's own defaults again
    assert direct.alpha(0) == pytest.approx(0.5)


def test_overrides_are_new_records_and_nothing_is_patched():
    # the sweep once swapped the learner class's __init__ while make_learner ran; now a new spec
    spec = taxi_spec("q")
    changed = with_overrides(spec, {"alpha": 0.25})
    assert changed.learner.kwargs["alpha"] == 0.25 and spec.learner.kwargs["alpha"] == 0.5
    assert SMDPQLearner.__init__.__qualname__ == "SMDPQLearner.__init__"
    learner = build(changed)
    assert type(learner) is SMDPQLearner and learner.alpha(0) == pytest.approx(0.25)
    assert learner.Q.data.unique().tolist() == [-20.0]  # the domain's init is kept


def test_train_config_fields_and_envs_per_learner():
    spec = with_overrides(taxi_spec(), {"steps": 1000, "threshold": 7, "envs_per_learner": 8})
    assert spec.train.steps == 1000 and spec.train.threshold == 7
    assert spec.train.eval_every == taxi_spec().train.eval_every
    assert spec.envs_per_learner == 8
    assert spec.learner is taxi_spec().learner  # no learner argument: the same record
    assert taxi_spec().train.steps == 60_000


def test_unknown_key_lists_what_can_be_swept():
    with pytest.raises(ValueError) as err:
        with_overrides(taxi_spec(), {"alfa": 0.1, "alpha": 0.1})
    message = str(err.value)
    assert message.startswith("cannot sweep alfa:")
    for allowed in ("steps", "eval_every", "envs_per_learner", "MaxQLearner", "alpha", "init"):
        assert allowed in message
    for refused in ("progress", "success_key", "graph", "n_learners"):
        with pytest.raises(ValueError, match=f"cannot sweep {refused}"):
            with_overrides(taxi_spec(), {refused: 1})


@pytest.mark.parametrize(
    "key, value", [("steps", 0.5), ("steps", True), ("envs_per_learner", 2.0), ("threshold", False)]
)
def test_wrong_types_for_train_fields(key, value):
    with pytest.raises(ValueError, match=f"{key} must be a"):
        with_overrides(taxi_spec(), {key: value})


def test_default_metric_is_throughput_on_continuing_domains():
    assert default_metric(registry.get("taxi")) == "final_eval_return"
    assert default_metric(registry.get("small-agv")) == "final_eval_throughput"


# ---------------------------------------------------------------------- run_sweep's checks
def test_user_errors_come_before_ray(tmp_path, monkeypatch):
    grid = {"alpha": [0.1]}
    with pytest.raises(ValueError, match="unknown domain"):
        run_sweep("taxy", "maxq-q", grid, 2, out=tmp_path)
    with pytest.raises(ValueError, match="has no algorithm 'maxq'"):
        run_sweep("taxi", "maxq", grid, 2, out=tmp_path)
    with pytest.raises(ValueError, match="both swept"):
        run_sweep("taxi", "maxq-q", {"steps": [10]}, 2, out=tmp_path, steps=10)
    with pytest.raises(ValueError, match="cannot sweep alfa"):
        run_sweep("taxi", "maxq-q", {"alfa": [0.1]}, 2, out=tmp_path, name="a")
    with pytest.raises(ValueError, match=r"configuration alpha=-1: .*alpha"):  # the learner's check
        run_sweep("taxi", "maxq-q", {"alpha": [0.5, -1]}, 2, out=tmp_path, name="b")
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the extra were not installed
    with pytest.raises(ValueError) as err:
        run_sweep("taxi", "maxq-q", grid, 2, out=tmp_path, name="c")
    assert str(err.value) == INSTALL_HINT


def test_a_started_sweep_is_resumed_only_with_the_same_request(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # stop where Ray would start
    grid = {"alpha": [0.1, 0.5]}
    with pytest.raises(ValueError, match="pip install"):
        run_sweep("taxi", "maxq-q", grid, 2, out=tmp_path, steps=100)
    sweep_dir = tmp_path / "taxi__maxq-q__sweep"
    recorded = json.loads((sweep_dir / "sweep.json").read_text())
    assert recorded["grid"] == {"alpha": [0.1, 0.5]} and recorded["seeds"] == [0, 1]
    with pytest.raises(ValueError, match="pip install"):  # never reached Ray: a new sweep again
        run_sweep("taxi", "maxq-q", {"alpha": [0.1]}, 2, out=tmp_path, steps=100)
    (sweep_dir / "tune").mkdir()  # as Tune leaves it
    with pytest.raises(ValueError, match="holds a sweep: pass --resume"):
        run_sweep("taxi", "maxq-q", {"alpha": [0.1]}, 2, out=tmp_path, steps=100)
    with pytest.raises(ValueError, match=r"--resume: grid .* differs"):
        run_sweep("taxi", "maxq-q", grid, 2, out=tmp_path, steps=100, resume=True)
    with pytest.raises(ValueError, match=r"--resume: seeds \[0, 1, 2\] differs"):
        run_sweep("taxi", "maxq-q", {"alpha": [0.1]}, 3, out=tmp_path, steps=100, resume=True)
    with pytest.raises(ValueError, match="pip install"):  # the same request: on to Ray
        run_sweep("taxi", "maxq-q", {"alpha": [0.1]}, 2, out=tmp_path, steps=100, resume=True)


def sweep_args(*argv):
    parser = argparse.ArgumentParser()
    add_sweep_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["sweep", *argv])


def test_command_line_parses_and_reports_bad_grids(tmp_path):
    args = sweep_args("taxi", "--algo", "maxq-q", "--grid", "alpha=0.1,0.5", "--grid", "init=0")
    assert (args.domain, args.algo, args.seeds, args.steps) == ("taxi", "maxq-q", 5, None)
    assert args.grid == ["alpha=0.1,0.5", "init=0"] and not args.resume
    bad = sweep_args("taxi", "--algo", "maxq-q", "--grid", "alpha", "--out", str(tmp_path))
    with pytest.raises(ValueError, match="grid item 'alpha'"):
        run_sweep_command(bad)


# ---------------------------------------------------------------------- a local Ray sweep
@pytest.mark.slow
def test_local_ray_sweep_ranks_its_trials_and_resumes(tmp_path, capsys):
    pytest.importorskip("ray")
    out = tmp_path / "runs"
    argv = ["taxi", "--algo", "maxq-q", "--grid", "alpha=0.05,0.5", "--seeds", "2"]
    argv += ["--steps", "6144", "--out", str(out), "--name", "s"]
    assert run_sweep_command(sweep_args(*argv)) == 0
    printed = capsys.readouterr().out
    sweep_dir = out / "s"
    assert (sweep_dir / "sweep.md").read_text() in printed

    rows = run_sweep(
        "taxi", "maxq-q", {"alpha": [0.05, 0.5]}, 2, out=out, steps=6144, name="s", resume=True
    )
    assert [r["status"] for r in rows] == ["finished", "finished"]
    assert sorted(r["config"]["alpha"] for r in rows) == [0.05, 0.5]
    means = []
    for row in rows:
        run_dir = sweep_dir / label(row["config"])
        (run_folder,) = run_dir.iterdir()  # one run folder per trial; resuming ran nothing again
        assert str(run_folder) == row["run_dir"]
        assert list((run_folder / "tb").glob("seed_*/events.out.tfevents.*"))
        summary = json.loads((run_folder / "summary.json").read_text())
        assert summary["env_steps_per_learner"] >= 6144 and summary["seeds"] == [0, 1]
        values = [r["final_eval_return"] for r in summary["per_seed"]]
        assert row["per_seed"] == values
        assert row["mean"] == pytest.approx(sum(values) / 2)
        means.append(row["mean"])
    assert [r["rank"] for r in rows] == [1, 2]
    assert means == sorted(means, reverse=True)
    table = (sweep_dir / "sweep.csv").read_text().splitlines()
    assert table[0].startswith("rank,alpha,IQM final_eval_return,IQM 95% low,IQM 95% high,mean")
    assert [line.split(",")[1] for line in table[1:]] == [str(r["config"]["alpha"]) for r in rows]


def test_a_trial_reruns_an_unfinished_run_and_reuses_a_finished_one(tmp_path, monkeypatch):
    tune = pytest.importorskip("ray.tune")
    from hrl_torch.runs.sweep import _trial

    reports = []
    monkeypatch.setattr(tune, "report", reports.append)
    domain = registry.get("taxi")
    config = {"alpha": 0.5, "envs_per_learner": 4, "eval_episodes": 3, "steps": 64}
    leftover = tmp_path / label(config) / "taxi__maxq-q__19990101-000000"
    leftover.mkdir(parents=True)  # an attempt stopped before its summary
    (leftover / "progress.csv").write_text("step,seed,metric,value\n")
    kwargs = dict(domain=domain, algo="maxq-q", seeds=[0, 1], steps=None, root=tmp_path)
    _trial(config, metric="final_eval_return", **kwargs)
    assert not leftover.exists()
    (run_dir,) = (tmp_path / label(config)).iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    values = [r["final_eval_return"] for r in summary["per_seed"]]
    assert reports[-1]["run_dir"] == str(run_dir)
    assert reports[-1]["seed_0"] == values[0] and reports[-1]["seed_1"] == values[1]
    assert reports[-1]["final_eval_return"] == pytest.approx(sum(values) / 2)
    assert summary["envs_per_learner"] == 4 and summary["env_steps_per_learner"] == 64
    _trial(config, metric="final_eval_return", **kwargs)  # finished: reported again, not rerun
    assert [p.name for p in (tmp_path / label(config)).iterdir()] == [run_dir.name]
    assert reports[-1] == reports[-2]
    with pytest.raises(KeyError, match="no per-seed 'final_eval_throughput'"):
        _trial(config, metric="final_eval_throughput", **kwargs)
