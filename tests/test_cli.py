"""The CLI writes a complete run folder and resumes from its checkpoint."""

import json

from hrl_torch.cli import main


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
