"""The CLI writes a complete run folder and resumes from its checkpoint."""

import json
import re
import subprocess
import sys
from pathlib import Path

from hrl_torch.runs.cli import main


def run(tmp_path, *extra):
    args = [
        "train",
        "taxi",
        "--algo",
        "maxq-q",
        "--seeds",
        "2",
        "--envs-per-seed",
        "8",
        "--eval-every",
        "400",
        "--eval-episodes",
        "5",
        "--out",
        str(tmp_path),
        "--no-progress",
        *extra,
    ]
    assert main(args) == 0
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    return run_dir


def test_train_writes_a_run_folder_and_resumes(tmp_path, capsys):
    run_dir = run(tmp_path, "--steps", "800")
    assert run_dir.name.startswith("taxi__maxq-q__")
    summary = json.loads((run_dir / "summary.json").read_text())
    assert [r["seed"] for r in summary["per_seed"]] == [0, 1]
    for r in summary["per_seed"]:
        assert {"final_eval_return", "env_steps", "wall_seconds", "env_steps_per_second"} <= set(r)
        assert 0 < r["env_steps"] <= 800
    csv_text = (run_dir / "progress.csv").read_text()
    assert csv_text.startswith("step,seed,metric,value") and "charts/eval_return" in csv_text
    assert (run_dir / "charts_eval_return.png").stat().st_size > 1000
    assert list((run_dir / "tb" / "seed_0").glob("events.out.tfevents.*"))
    assert (run_dir / "checkpoint.pt").exists()
    assert "final eval return" in capsys.readouterr().out
    # the record is what ran: the options' budget, not the domain's default, and the code
    hparams = json.loads((run_dir / "hparams.json").read_text())
    assert hparams["train.steps"] == 800 and hparams["train.eval_every"] == 400
    assert hparams["envs_per_learner"] == 8
    assert set(hparams["code"]) == {"version", "commit", "dirty"}
    assert hparams["learner"]["class"] == "MaxQLearner" and hparams["learner"]["gamma"] == 1.0
    assert hparams["learner"]["alpha"] == "Constant(value=0.5)"
    assert hparams["exploration"]["epsilon"].startswith("Linear(start=1.0, end=0.05")
    from hrl_torch.common.checkpoint import load_checkpoint

    assert load_checkpoint(run_dir / "checkpoint.pt")["run"]["code"] == hparams["code"]

    main(
        [
            "train",
            "taxi",
            "--algo",
            "maxq-q",
            "--seeds",
            "2",
            "--envs-per-seed",
            "8",
            "--eval-every",
            "400",
            "--eval-episodes",
            "5",
            "--no-progress",
            "--steps",
            "1600",
            "--resume",
            str(run_dir / "checkpoint.pt"),
        ]
    )
    resumed = json.loads((run_dir / "summary.json").read_text())
    assert resumed["env_steps_per_learner"] == 1600


def test_help_version_and_usage_import_no_torch():
    """``--help``, ``--version`` and a bare ``hrl-torch`` answer without importing torch."""
    probe = (
        "import sys, contextlib, io\n"
        "from hrl_torch.runs.cli import main\n"
        "for argv in (['--help'], ['--version'], ['train', '--help']):\n"
        "    with contextlib.redirect_stdout(io.StringIO()) as out:\n"
        "        try:\n"
        "            main(argv)\n"
        "        except SystemExit as stop:\n"
        "            assert stop.code == 0, (argv, stop.code)\n"
        "    assert out.getvalue().strip(), argv\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
        "    assert main([]) == 2\n"
        "assert out.getvalue().startswith('usage: hrl-torch'), out.getvalue()\n"
        "assert 'torch' not in sys.modules and 'tensordict' not in sys.modules\n"
    )
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run(
        [sys.executable, "-c", probe], cwd=root, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr


def test_every_option_has_help_text():
    from hrl_torch.runs.cli_parser import parser

    def actions(p):
        for action in p._actions:
            yield p, action
            for sub in getattr(action, "choices", None) or {}:
                if isinstance(action.choices, dict):
                    yield from actions(action.choices[sub])

    missing = [
        (p.prog, a.dest) for p, a in actions(parser("0")) if not a.help and a.dest != "command"
    ]
    assert not missing


def test_no_progress_prints_each_evaluation_as_it_happens(tmp_path, capsys):
    run(tmp_path, "--steps", "800")  # evaluations at 400 and 800 (eval_every 400)
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("eval at step")]
    assert len(lines) == 2 and lines[0].startswith("eval at step 400: greedy return ")
    assert "(2 seeds " in lines[0] and re.search(r"\) \[\d+(\.\d+)? s\]", lines[0]), lines[0]
    # an untrained taxi loops: the line names the episodes at the step limit and their cycle
    assert "greedy episode(s) hit the step limit" in lines[0]


def test_an_all_nan_evaluation_says_why():
    from hrl_torch.training.evaluation import eval_line

    line = eval_line(64, "charts/eval_throughput", [float("nan")] * 2, 1.0)
    assert line.startswith("eval at step 64: greedy throughput nan for every seed: ")


def test_list_shows_budgets_and_timed_training(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    budget = "60,000 env steps per seed in all, 256 envs in parallel (235 steps each)"
    assert f"on the MAXQ task graph [{budget}]" in out
    from hrl_torch.runs import registry
    from hrl_torch.runs.cli import _training_seconds

    seconds = _training_seconds(registry.get("taxi"), "q", steps=2)
    assert 0 < seconds < 3600
