"""The README's training script runs as written (with a smaller budget)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_readme_training_script_runs(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    script = next(b for b in blocks if "Trainer(" in b)
    smaller = {
        "envs_per_learner=256": "envs_per_learner=8",
        "steps=60_000": "steps=2_000",
        "eval_every=5_000": "eval_every=1_000",
        "envs_per_learner=100": "envs_per_learner=10",
        "seeds = list(range(10))": "seeds = list(range(2))",
    }
    for old, new in smaller.items():
        assert old in script, f"the README script changed: update this test ({old})"
        script = script.replace(old, new)
    script = script.replace("TrainConfig(", "TrainConfig(progress=False, eval_max_steps=100, ")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(script, "README.md", "exec"), namespace)
    result = namespace["result"]
    assert len(result.final_eval) == 2 and result.env_steps_per_learner == 2_000
    assert (tmp_path / "taxi.pt").exists()
