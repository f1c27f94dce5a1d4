"""Runs that survive users: resume from the checkpoint alone, Ctrl-C / SIGTERM that saves, a
crash between checkpoints, a longer budget, a finished run, and refused changes."""

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from hrl_torch.common.checkpoint import load_checkpoint
from hrl_torch.runs import registry
from hrl_torch.runs.cli import main
from hrl_torch.runs.experiment import RunOptions, run_experiment
from hrl_torch.training.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--seeds", "2", "--envs-per-seed", "4", "--eval-every", "200", "--eval-episodes", "3"]


def train(out, *extra) -> int:
    return main(
        ["train", "taxi", "--algo", "maxq-q", *SMALL, "--out", str(out), "--no-progress", *extra]
    )


def resume(run_dir, *extra) -> int:
    return main(["train", "--resume", str(run_dir / "checkpoint.pt"), "--no-progress", *extra])


def the_run(out) -> Path:
    (run_dir,) = [p for p in Path(out).iterdir() if p.is_dir()]
    return run_dir


def logged(run_dir) -> list[tuple]:
    """progress.csv's rows, timings (``perf/``) left out, then eval_episodes.csv's, in order."""
    with open(run_dir / "progress.csv", newline="") as f:
        rows = [tuple(r) for r in csv.reader(f) if not r[2].startswith("perf/")]
    with open(run_dir / "eval_episodes.csv", newline="") as f:
        return rows + [tuple(r) for r in csv.reader(f)]


def tables(run_dir) -> dict:
    return load_checkpoint(run_dir / "checkpoint.pt")["trainer"]["learner"]


def assert_same_tables(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k


def snapshot(folder) -> dict:
    return {p: p.read_bytes() for p in Path(folder).rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    """One uninterrupted 800-step run, the reference of the continuations."""
    out = tmp_path_factory.mktemp("straight")
    assert train(out, "--steps", "800") == 0
    return the_run(out)


def test_resume_from_the_checkpoint_alone_keeps_the_original_settings(tmp_path, straight, capsys):
    assert train(tmp_path, "--steps", "400") == 0
    run_dir = the_run(tmp_path)
    assert resume(run_dir, "--steps", "800") == 0
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["seeds"] == [0, 1] and summary["env_steps_per_learner"] == 800
    assert summary["status"] == "finished"
    hparams = json.loads((run_dir / "hparams.json").read_text())
    assert hparams["options.steps"] == 400  # the original settings stay
    (record,) = hparams["resumes"]
    assert record["at_step"] == 400 and record["options.steps"] == 800
    # the schedules stayed those of the 400-step budget: the same as one run with that budget
    out = tmp_path / "long"
    opts = RunOptions(
        seeds=[0, 1],
        envs_per_learner=4,
        steps=800,
        schedule_steps=400,
        eval_every=200,
        eval_episodes=3,
        out=str(out),
        progress=False,
    )
    run_experiment(registry.get("taxi"), "maxq-q", opts)
    assert_same_tables(tables(run_dir), tables(the_run(out)))
    assert logged(run_dir) == logged(the_run(out))


def test_ctrl_c_saves_and_the_resumed_run_equals_the_uninterrupted_one(
    tmp_path, straight, capsys, monkeypatch
):
    step = Trainer.train_step

    def interrupted_at_300(self):
        step(self)
        if self.step == 300:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(Trainer, "train_step", interrupted_at_300)
    assert train(tmp_path, "--steps", "800") == 130
    run_dir = the_run(tmp_path)
    ckpt = run_dir / "checkpoint.pt"
    assert capsys.readouterr().err.strip().splitlines() == [
        f"hrl-torch: SIGINT at step 300: checkpoint written; continue with: "
        f"hrl-torch train --resume {ckpt}"
    ]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert (summary["status"], summary["interrupted_by"]) == ("interrupted", "SIGINT")
    assert load_checkpoint(ckpt)["trainer"]["step"] == 300
    assert not list(run_dir.glob("*.tmp"))

    monkeypatch.setattr(Trainer, "train_step", step)
    assert resume(run_dir) == 0  # no options: the checkpoint's own budget
    assert_same_tables(tables(run_dir), tables(straight))
    assert logged(run_dir) == logged(straight)


def test_sigterm_exits_143(tmp_path, capsys, monkeypatch):
    step = Trainer.train_step

    def terminated_at_100(self):
        step(self)
        if self.step == 100:
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(Trainer, "train_step", terminated_at_100)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    assert train(tmp_path, "--steps", "800") == 143
    assert "hrl-torch: SIGTERM at step 100" in capsys.readouterr().err
    # the handlers are back: a signal outside training acts as it did before (the default
    # one, or an ignored SIGINT in a background job)
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_a_crash_between_checkpoints_logs_no_step_twice(tmp_path, straight, monkeypatch):
    step = Trainer.train_step

    def crash_at_604(self):
        step(self)
        if self.step == 604:  # after the evaluation at 600
            raise RuntimeError("power cut")

    monkeypatch.setattr(Trainer, "train_step", crash_at_604)
    assert train(tmp_path, "--steps", "800", "--checkpoint-every", "200") == 1
    run_dir = the_run(tmp_path)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["reason"] == "power cut"
    ckpt_step = load_checkpoint(run_dir / "checkpoint.pt")["trainer"]["step"]
    assert ckpt_step == 404  # checkpoints at 4, 204, 404 (the clock moves E = 4 per step)
    steps = [int(r[0]) for r in logged(run_dir) if r[0] != "step"]
    assert max(steps) > ckpt_step  # rows logged after it

    monkeypatch.setattr(Trainer, "train_step", step)
    assert resume(run_dir) == 0
    assert logged(run_dir) == logged(straight)  # the rows after the checkpoint were dropped
    assert_same_tables(tables(run_dir), tables(straight))


def test_a_finished_run_resumed_says_so_and_changes_nothing(straight, capsys):
    before = snapshot(straight)
    assert resume(straight) == 0
    ckpt = straight / "checkpoint.pt"
    assert capsys.readouterr().out.strip() == (
        f"{ckpt}: the run finished at step 800 (budget 800); nothing to do "
        "(pass --steps N > 800 to continue it)"
    )
    assert resume(straight, "--steps", "600") == 0
    assert snapshot(straight) == before


CHANGES = {
    "--seeds 5": "seeds [0, 1, 2, 3, 4] differs from the checkpoint's run (seeds [0, 1])",
    "--seed-offset 100": "seeds [100, 101, 102, 103, 104] differs from the checkpoint's run "
    "(seeds [0, 1])",
    "--envs-per-seed 8": "envs_per_learner 8 differs from the checkpoint's run "
    "(envs_per_learner 4)",
    "--eval-every 100": "eval_every 100 differs from the checkpoint's run (eval_every 200)",
    "--backend gymnasium": "backend 'gymnasium' differs from the checkpoint's run "
    "(backend 'torch')",
    "--collector": "collector True differs from the checkpoint's run (collector False)",
    "agv": "domain 'agv' differs from the checkpoint's run (domain 'taxi')",
}
SUFFIX = "; a resumed run keeps its settings (only steps and checkpoint_every may change)"


@pytest.mark.parametrize("change", list(CHANGES))
def test_a_change_of_the_run_is_refused_in_one_line(change, straight, capsys):
    before = snapshot(straight)
    extra = change.split()
    head = extra if not change.startswith("-") else []
    flags = [] if head else extra
    args = ["train", *head, "--resume", str(straight / "checkpoint.pt"), "--steps", "900", *flags]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"hrl-torch: error: {CHANGES[change]}{SUFFIX}"]
    assert snapshot(straight) == before


def test_out_and_missing_arguments(straight, tmp_path, capsys):
    args = ["train", "--resume", str(straight / "checkpoint.pt"), "--out", str(tmp_path)]
    assert main(args) == 2
    assert capsys.readouterr().err.strip() == (
        "hrl-torch: error: --out does not apply to --resume: a run continues in its own folder"
    )
    assert main(["train", "taxi", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == (
        "hrl-torch: error: train needs --algo (or --resume CHECKPOINT)"
    )
    assert main(["train", "--algo", "maxq-q"]) == 2
    assert capsys.readouterr().err.strip() == (
        "hrl-torch: error: train needs the domain (or --resume CHECKPOINT)"
    )
    assert not list(tmp_path.iterdir())


def test_a_real_ctrl_c_on_the_command_line(tmp_path):
    """The installed command in its own process: SIGINT once training logs, exit 130."""
    cmd = [sys.executable, "-m", "hrl_torch.runs.cli", "--project", str(ROOT), "train", "taxi"]
    cmd += ["--algo", "maxq-q", *SMALL, "--steps", "100000000", "--out", str(tmp_path)]
    cmd += ["--no-progress", "--no-tensorboard"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # wait for the first evaluation's rows
        runs = [p for p in tmp_path.iterdir() if p.is_dir()]
        if runs and "charts/eval_return" in _text(runs[0] / "progress.csv"):
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    (line,) = err.strip().splitlines()
    assert line.startswith("hrl-torch: SIGINT at step ") and line.endswith("checkpoint.pt")
    run_dir = the_run(tmp_path)
    state = load_checkpoint(run_dir / "checkpoint.pt")
    assert state["run"]["steps"] == 100000000 and state["trainer"]["step"] > 0
    assert json.loads((run_dir / "summary.json").read_text())["status"] == "interrupted"


def _text(path: Path) -> str:
    return path.read_text() if path.exists() else ""


def test_the_library_resumes_from_the_checkpoint_alone(tmp_path):
    from hrl_torch.runs import registry
    assert train(tmp_path, "--steps", "400") == 0
    run_dir = the_run(tmp_path)
    opts = RunOptions(resume=str(run_dir / "checkpoint.pt"), steps=800, progress=False)
    again, summary = run_experiment(registry.get("taxi"), "maxq-q", opts)
    assert again == run_dir and summary["seeds"] == [0, 1]
    assert summary["env_steps_per_learner"] == 800 and summary["envs_per_learner"] == 4
    with pytest.raises(ValueError, match=r"seeds \[5\] differs from the checkpoint's run"):
        run_experiment(registry.get("taxi"), "maxq-q", replace(opts, seeds=[5]))


def test_a_row_cut_short_by_a_crash_is_dropped_on_resume_at_any_byte(tmp_path):
    """A crash at any byte of the last CSV write: the resumed log holds whole rows only."""
    from hrl_torch.training.runlog import RunLogger, read_curves

    whole = "step,seed,metric,value\n" + "".join(
        f"{s},0,charts/eval_return,{s / 10:.6g}\n" for s in (4, 8, 12, 16)
    )
    last_row_start = whole.index("16,0")
    for cut in range(last_row_start, len(whole)):
        run = tmp_path / f"cut{cut}"
        run.mkdir()
        (run / "progress.csv").write_text(whole[:cut])
        RunLogger(run, [0], {}, tensorboard=False, resumed_at=16).close()
        assert (run / "progress.csv").read_text() == whole[:last_row_start], cut
        steps, _ = read_curves(run / "progress.csv", "charts/eval_return")
        assert list(steps) == [4, 8, 12]


def test_a_second_writer_of_a_run_folder_is_refused_and_changes_nothing(tmp_path, capsys):
    from hrl_torch.runs.runlock import RunLock

    assert train(tmp_path, "--steps", "400") == 0
    run_dir = the_run(tmp_path)
    capsys.readouterr()
    with RunLock(run_dir):  # a resume of this folder is running (another open file: refused)
        before = snapshot(run_dir)
        assert resume(run_dir, "--steps", "800") == 2
        assert snapshot(run_dir) == before
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"hrl-torch: error: {run_dir} is in use by process {os.getpid()} (another run or "
        "resume writes it); wait for it to end"
    ]
    assert resume(run_dir, "--steps", "800") == 0  # the lock goes with its holder


def test_two_concurrent_resumes_one_is_refused(tmp_path):
    assert train(tmp_path, "--steps", "400") == 0
    run_dir = the_run(tmp_path)
    cmd = [
        sys.executable,
        "-m",
        "hrl_torch.runs.cli",
        "train",
        "--resume",
        str(run_dir / "checkpoint.pt"),
    ]
    cmd += ["--steps", "40000", "--no-progress"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    first = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.time() + 60
        lock = run_dir / ".lock"  # the holder writes its pid once it holds the lock
        while lock.read_text().strip() != str(first.pid):
            assert time.time() < deadline and first.poll() is None, first.stderr.read()
            time.sleep(0.1)
        second = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
        assert second.returncode == 2
        assert f"is in use by process {first.pid}" in second.stderr
    finally:
        first.send_signal(signal.SIGINT)
        first.wait(timeout=120)
    resumes = json.loads((run_dir / "hparams.json").read_text())["resumes"]
    assert len(resumes) == 1


def test_a_checkpoint_that_does_not_fit_is_one_line_and_changes_nothing(
    trained_run, tmp_path, capsys
):
    run_dir = tmp_path / "copy"
    shutil.copytree(trained_run, run_dir)
    state = torch.load(run_dir / "checkpoint.pt", weights_only=True)
    key = next(k for k in state["trainer"]["learner"] if k.endswith(".C"))
    state["trainer"]["learner"][key] = torch.zeros(3, 3)  # a wrong-shape table
    torch.save(state, run_dir / "checkpoint.pt")
    before = snapshot(run_dir)
    capsys.readouterr()
    assert resume(run_dir, "--steps", "800") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hrl-torch: error: ") and "fit" in err[0], err
    assert snapshot(run_dir) == before  # hparams.json, CSVs, TensorBoard: untouched


def test_a_checkpoint_whose_tables_hold_nan_is_refused(trained_run, tmp_path, capsys):
    run_dir = tmp_path / "copy"
    shutil.copytree(trained_run, run_dir)
    state = torch.load(run_dir / "checkpoint.pt", weights_only=True)
    key = next(k for k in state["trainer"]["learner"] if k.endswith(".C"))
    state["trainer"]["learner"][key].view(-1)[0] = float("nan")
    torch.save(state, run_dir / "checkpoint.pt")
    before = snapshot(run_dir)
    capsys.readouterr()
    assert resume(run_dir, "--steps", "800") == 2
    err = capsys.readouterr().err.strip()
    assert err == f"hrl-torch: error: checkpoint does not fit this run: learner {key} holds NaN"
    assert snapshot(run_dir) == before


def test_a_checkpoint_whose_recorded_seeds_were_edited_is_refused(trained_run, tmp_path, capsys):
    run_dir = tmp_path / "copy"
    shutil.copytree(trained_run, run_dir)
    for seeds in ([5, 6], [0, 1, 2]):
        state = torch.load(run_dir / "checkpoint.pt", weights_only=True)
        state["run"]["seeds"] = seeds
        torch.save(state, run_dir / "edited.pt")
        before = snapshot(run_dir)
        capsys.readouterr()
        assert main(["train", "--resume", str(run_dir / "edited.pt"), "--steps", "800"]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert line.startswith("hrl-torch: error: checkpoint does not fit this run: "), line
        assert snapshot(run_dir) == before and not (run_dir / "tb" / "seed_2").exists()


def test_a_full_disk_at_a_checkpoint_is_one_line_and_keeps_the_previous_one(
    tmp_path, capsys, monkeypatch
):
    import hrl_torch.common.checkpoint as checkpoint_module

    save, calls = checkpoint_module.torch.save, []

    def full_disk_from_the_second_write(obj, path, *args, **kwargs):
        calls.append(path)
        if len(calls) > 1:
            raise RuntimeError(
                "[enforce fail at inline_container.cc:664] . unexpected pos\\n"
                "basic_ios::clear: iostream error"
            )
        return save(obj, path, *args, **kwargs)

    monkeypatch.setattr(checkpoint_module.torch, "save", full_disk_from_the_second_write)
    assert train(tmp_path, "--steps", "800", "--checkpoint-every", "200") == 1
    run_dir = the_run(tmp_path)
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("hrl-torch: failed: ") and "continue from step 4 with" in line, line
    assert load_checkpoint(run_dir / "checkpoint.pt")["trainer"]["step"] == 4
    assert not list(run_dir.glob("*.tmp"))
    assert json.loads((run_dir / "summary.json").read_text())["status"] == "failed"
