"""``hrl-torch train --logger csv|wandb|mlflow``: torchrl's loggers in the run folder, read back.

The CSV logger needs nothing more (fast); W&B (offline) and MLflow (SQLite) need the ``track``
extra and are slow (importing them and creating MLflow's database take seconds each).
"""

import csv
import importlib.util
import json
import os
import struct
from pathlib import Path

import pytest

from hrl_torch.runs.cli import main
from hrl_torch.runs.experiment import RunOptions
from hrl_torch.training.trackers import check_trackers

SMALL = ["taxi", "--algo", "maxq-q", "--seeds", "2", "--envs-per-seed", "8", "--steps", "400"]
SMALL += ["--eval-every", "200", "--eval-episodes", "2", "--no-progress"]
SMALL += ["--set", "learner.alpha=0.25"]


def train(out, *loggers) -> Path:
    assert main(["train", *SMALL, "--out", str(out), *loggers]) == 0
    (run_dir,) = [p for p in Path(out).iterdir() if p.is_dir()]
    return run_dir


def progress(run_dir: Path, metric: str) -> dict:
    """``{(step, seed): value}`` of one metric in progress.csv."""
    with open(run_dir / "progress.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["metric"] == metric]
    return {(int(r["step"]), int(r["seed"])): float(r["value"]) for r in rows}


def no_links(run_dir: Path) -> bool:
    return not any(p.is_symlink() for p in run_dir.rglob("*"))


def test_the_csv_logger_writes_each_metric_s_seed_mean_in_the_run_folder(tmp_path):
    run_dir = train(tmp_path / "runs", "--logger", "csv")
    assert not (run_dir / "tb").exists()  # --logger names every logger: TensorBoard is not one
    logged = run_dir / "csv" / "scalars" / "charts" / "eval_return.csv"
    rows = [line.split(",") for line in logged.read_text().split()]
    seeds = progress(run_dir, "charts/eval_return")
    expected = {s: (seeds[(s, 0)] + seeds[(s, 1)]) / 2 for s, _ in seeds}
    assert {int(step): float(v) for step, v in rows} == pytest.approx(expected, rel=1e-5)
    hparams = (run_dir / "csv" / "texts" / "hparams0.txt").read_text()
    assert "settings.learner.alpha: 0.25" in hparams and "seeds: [0, 1]" in hparams
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]  # nothing outside it


def test_tensorboard_and_csv_together_and_unknown_or_missing_loggers_in_one_line(
    tmp_path, capsys
):
    run_dir = train(tmp_path, "--logger", "tensorboard,csv")
    assert (run_dir / "tb" / "seed_1").is_dir() and (run_dir / "csv").is_dir()
    assert main(["train", *SMALL, "--out", str(tmp_path / "b"), "--logger", "neptune"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "hrl-torch: error: unknown logger 'neptune': choose from tensorboard, csv, wandb, mlflow"
    )
    assert not (tmp_path / "b").exists()
    with pytest.raises(ValueError, match="unknown logger 'tb'"):
        RunOptions(trackers=["tb"])


def test_a_missing_tracker_package_names_the_extra(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "wandb" else real(name, *a)
    )
    with pytest.raises(ValueError) as err:
        check_trackers(["csv", "wandb"])
    assert str(err.value) == (
        "--logger wandb needs wandb, which is not installed: pip install 'hrl-torch[track]'"
    )


needs_track = pytest.mark.skipif(
    importlib.util.find_spec("wandb") is None or importlib.util.find_spec("mlflow") is None,
    reason="the track extra is not installed",
)


@pytest.mark.slow
@needs_track
def test_mlflow_s_client_lists_the_run_s_metrics_and_params(tmp_path):
    from mlflow.tracking import MlflowClient

    run_dir = train(tmp_path / "runs", "--logger", "mlflow")
    client = MlflowClient(tracking_uri=f"sqlite:///{run_dir.resolve() / 'mlflow.db'}")
    (experiment,) = [e for e in client.search_experiments() if e.name == "hrl-torch"]
    (run,) = client.search_runs([experiment.experiment_id])
    assert run.info.run_name == run_dir.name and run.info.status == "FINISHED"
    params = run.data.params
    assert params["settings.learner.alpha"] == "0.25" and params["seeds"] == "[0, 1]"
    assert params["domain"] == "taxi" and params["train.steps"] == "400"
    seeds = progress(run_dir, "charts/eval_return")
    for seed in (0, 1):
        history = client.get_metric_history(run.info.run_id, f"charts/eval_return/seed_{seed}")
        got = {m.step: m.value for m in history}
        assert got == pytest.approx({t: v for (t, s), v in seeds.items() if s == seed}, rel=1e-5)
    history = client.get_metric_history(run.info.run_id, "charts/eval_return")
    mean = {m.step: m.value for m in history}
    assert mean[400] == pytest.approx((seeds[(400, 0)] + seeds[(400, 1)]) / 2, rel=1e-5)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]
    assert os.environ.get("MLFLOW_DISABLE_TELEMETRY") is None  # restored after the run


def key(item) -> str:
    return item.key or "/".join(item.nested_key)  # (W&B may store a key by its parts)


def wandb_records(path: Path):
    """The records of a W&B ``.wandb`` file: LevelDB-log chunks of ``wandb_internal.Record``."""
    from wandb.proto import wandb_internal_pb2

    data = path.read_bytes()
    assert data[:4] == b":W&B"
    pos, block, chunks = 7, 32768, b""
    while pos + 7 <= len(data):
        if block - pos % block < 7:  # a block's tail too short for a header is padding
            pos += block - pos % block
            continue
        _, length, kind = struct.unpack("<IHB", data[pos : pos + 7])
        chunks += data[pos + 7 : pos + 7 + length]
        pos += 7 + length
        if kind in (1, 4):  # a full record, or the last piece of one
            record = wandb_internal_pb2.Record()
            record.ParseFromString(chunks)
            chunks = b""
            yield record


@pytest.mark.slow
@needs_track
def test_the_wandb_offline_run_folder_holds_the_metrics_and_config(tmp_path):
    run_dir = train(tmp_path / "runs", "--logger", "wandb")
    (offline,) = (run_dir / "wandb").glob("offline-run-*")
    (log,) = offline.glob("run-*.wandb")
    records = list(wandb_records(log))
    kinds = [r.WhichOneof("record_type") for r in records]
    assert kinds[-1] == "exit"  # the run was finished
    (run,) = [r.run for r in records if r.WhichOneof("record_type") == "run"]
    assert run.display_name == run_dir.name and run.run_group == "taxi__maxq-q"
    config = {
        key(item): json.loads(item.value_json)
        for r in records
        if r.WhichOneof("record_type") == "config"
        for item in r.config.update
    }
    assert config["settings.learner.alpha"] == 0.25 and config["seeds"] == "[0, 1]"
    history = [
        {key(item): json.loads(item.value_json) for item in r.history.item}
        for r in records
        if r.WhichOneof("record_type") == "history"
    ]
    seeds = progress(run_dir, "charts/eval_return")
    logged = {
        (h["charts/step"], s): h[f"charts/eval_return/seed_{s}"]
        for h in history
        for s in (0, 1)
        if f"charts/eval_return/seed_{s}" in h
    }
    assert logged == pytest.approx(seeds, rel=1e-5)
    assert no_links(run_dir)  # W&B's latest-run and debug.log links are gone
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]
    assert main(["train", "--resume", str(run_dir / "checkpoint.pt"), "--steps", "600",
                 "--no-progress", "--logger", "wandb"]) == 0  # fmt: skip
    assert len(list((run_dir / "wandb").glob("offline-run-*"))) == 2


def test_an_in_process_sweep_s_trials_log_to_the_trackers(tmp_path):
    from hrl_torch.runs.sweep import run_sweep

    grid = {"learner.alpha": [0.25, 0.5]}
    rows = run_sweep("taxi", "maxq-q", grid, 1, out=tmp_path, steps=256, in_process=True,
                     loggers=["csv"])  # fmt: skip
    assert [r["status"] for r in rows] == ["finished"] * 2
    for row in rows:
        run_dir = Path(row["run_dir"])
        assert (run_dir / "csv" / "scalars").is_dir() and not (run_dir / "tb").exists()
    assert main(["sweep", "taxi", "--algo", "maxq-q", "--grid", "learner.alpha=0.1", "--population",
                 "--logger", "csv", "--out", str(tmp_path / "p")]) == 2  # fmt: skip
