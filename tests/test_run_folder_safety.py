"""Nothing is written outside a run folder: planted links are refused, run folders are made
atomically, and a checkpoint continues only its own run's folder."""

import os
import shutil
import threading
import time
from pathlib import Path

import pytest

from hrl_torch.common.safe_files import RunFolderError, open_own, replace_file
from hrl_torch.runs.cli import main
from hrl_torch.training import runlog
from tests.run_folders import refused_lines, the_run, train

SECRET = b"a file outside the run: must not change\n"


#: the run folder's entries a link is planted at, and whether it points at a folder
PLANTED = {
    ".lock": False,
    "hparams.json": False,
    "summary.json": False,
    "progress.csv": False,
    "eval_episodes.csv": False,
    "checkpoint.pt.tmp": False,
    "charts_eval_return.png": False,
    "tb": True,
    "tb/seed_0": True,
}


@pytest.mark.parametrize("name", list(PLANTED))
def test_a_planted_link_is_refused_and_the_outside_stays_byte_for_byte(
    name, trained_run, tmp_path, capsys
):
    sentinel, sentinel_dir = tmp_path / "sentinel", tmp_path / "outside"
    sentinel.write_bytes(SECRET)
    sentinel_dir.mkdir()
    (sentinel_dir / "kept").write_bytes(SECRET)
    run_dir = tmp_path / "sent"
    shutil.copytree(trained_run, run_dir)
    target = run_dir / name
    if target.is_dir():
        shutil.rmtree(target)
    else:
        target.unlink(missing_ok=True)
    target.symlink_to(sentinel_dir if PLANTED[name] else sentinel)
    for line in refused_lines(run_dir, capsys):
        assert line.startswith("hrl-torch: error: ") and "symbolic link" in line, line
        assert str(target) in line
    assert sentinel.read_bytes() == SECRET
    assert [p.name for p in sentinel_dir.iterdir()] == ["kept"]
    assert (sentinel_dir / "kept").read_bytes() == SECRET


def test_a_hard_link_to_an_outside_file_is_refused(trained_run, tmp_path, capsys):
    sentinel = tmp_path / "sentinel"
    sentinel.write_bytes(SECRET)
    run_dir = tmp_path / "sent"
    shutil.copytree(trained_run, run_dir)
    (run_dir / "hparams.json").unlink()
    os.link(sentinel, run_dir / "hparams.json")
    assert main(["train", "--resume", str(run_dir / "checkpoint.pt"), "--steps", "800"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "hard link" in line and "hparams.json" in line, line
    assert sentinel.read_bytes() == SECRET


def test_open_own_follows_no_link_and_truncates_only_after_the_check(tmp_path):
    sentinel = tmp_path / "sentinel"
    sentinel.write_bytes(SECRET)
    (tmp_path / "soft").symlink_to(sentinel)
    os.link(sentinel, tmp_path / "hard")
    for name in ("soft", "hard"):
        with pytest.raises(RunFolderError, match=name):
            open_own(tmp_path / name, "w")
    (tmp_path / "folder").mkdir()
    with pytest.raises(RunFolderError, match="is a folder"):
        open_own(tmp_path / "folder", "a")
    (tmp_path / "x.tmp").symlink_to(sentinel)  # a planted .tmp is removed, not written through
    replace_file(tmp_path / "x", lambda f: f.write("mine"))
    assert (tmp_path / "x").read_text() == "mine" and sentinel.read_bytes() == SECRET


def test_a_dangling_link_at_the_next_run_folders_name_is_a_clash(tmp_path, monkeypatch):
    monkeypatch.setattr(runlog.time, "strftime", lambda fmt: "20260101-000000")
    (tmp_path / "taxi__q__20260101-000000").symlink_to(tmp_path / "nowhere")
    (tmp_path / "taxi__q__20260101-000000-1").mkdir()
    made = runlog.make_run_dir(tmp_path, "taxi", "q")
    assert made.name == "taxi__q__20260101-000000-2" and made.is_dir() and not made.is_symlink()
    assert not (tmp_path / "nowhere").exists()


def test_eight_threads_making_run_folders_at_once_each_get_their_own(tmp_path, monkeypatch):
    monkeypatch.setattr(runlog.time, "strftime", lambda fmt: "20260101-000000")
    real_mkdir = Path.mkdir

    def slow_mkdir(self, *args, **kwargs):  # widens any gap between a check and the mkdir
        time.sleep(0.001)
        return real_mkdir(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", slow_mkdir)
    made, errors = [], []

    def make():
        try:
            made.extend(runlog.make_run_dir(tmp_path / "runs", "taxi", "q") for _ in range(20))
        except Exception as err:  # (FileExistsError: check and create were two steps)
            errors.append(err)

    threads = [threading.Thread(target=make) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(made) == 160 and len(set(made)) == 160


def test_an_out_of_4000_characters_is_one_line(tmp_path, capsys):
    out = tmp_path / "/".join(["d" * 200] * 20)  # each part allowed, the whole too long
    assert train(out) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("hrl-torch: error: ") and "too long" in line, line


def test_a_checkpoint_of_another_run_is_refused_in_its_folder(trained_run, tmp_path, capsys):
    other = tmp_path / "other"
    assert train(other, "q") == 0
    run_dir = tmp_path / "mixed"
    shutil.copytree(trained_run, run_dir)
    shutil.copy(the_run(other) / "checkpoint.pt", run_dir / "checkpoint.pt")
    for line in refused_lines(run_dir, capsys):
        assert "a checkpoint of another run than its folder's (algo" in line, line
