"""Every ```python block of README.md and docs/ runs as written, page by page, in order.

A page's blocks run in one namespace, as a reader pastes them one after another. A block right
after a line ``<!-- fragment -->`` is shown on purpose as a piece of a larger file and is not run.
Training budgets are shrunk by the substitutions below; each must still be found in its page, so
a changed page fails here until this table is updated.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"^(<!-- fragment -->\n)?```python\n(.*?)^```", re.S | re.M)

SMALLER = {
    "README.md": {
        "envs_per_learner=256": "envs_per_learner=8",
        "steps=60_000": "steps=2_000",
        "eval_every=5_000": "eval_every=1_000",
        "envs_per_learner=100": "envs_per_learner=10",
        "seeds = list(range(10))": "seeds = list(range(2))",
        'trainer.save("taxi.pt")': 'trainer.save("taxi.pt")',
    },
    "docs/your-own-hierarchy.md": {
        "seeds, steps = [0, 1, 2], 20_000": "seeds, steps = [0, 1], 1_000",
        "eval_episodes=50": "eval_episodes=5",
    },
    "docs/your-own-hybrid.md": {
        "seeds, steps = [0, 1, 2], 40_000": "seeds, steps = [0, 1], 400",
        "eval_episodes=100": "eval_episodes=5",
        "TwoDoorEnv([123] * len(seeds), 100)": "TwoDoorEnv([123] * len(seeds), 5)",
        "eval_every=steps // 4": "eval_every=0",
    },
    "docs/sweeps.md": {"seeds=5, steps=15_000": "seeds=2, steps=500"},
    "docs/multiagent-walkthrough.md": {
        "seeds, steps = [0, 1, 2], 12_000": "seeds, steps = [0, 1], 600",
        "eval_episodes=50": "eval_episodes=5",
        "num_cycles=100": "num_cycles=20",
    },
    "docs/existing-envs.md": {
        "seeds, steps = [0, 1, 2, 3], 4_000": "seeds, steps = [0, 1], 200",
        "reach_env(seeds, 8)": "reach_env(seeds, 4)",
        "seeds, steps = [0, 1, 2, 3], 6_000": "seeds, steps = [0, 1], 100",
        "eval_episodes=20": "eval_episodes=2",
        "spread_env(seeds, 8)": "spread_env(seeds, 2)",
    },
}
NEEDS = {"docs/sweeps.md": "ray", "docs/existing-envs.md": "mpe2"}  # optional extras


def blocks(page: str) -> list[str]:
    """The page's runnable python blocks, in order."""
    text = (ROOT / page).read_text()
    return [code for fragment, code in BLOCK.findall(text) if not fragment]


def test_the_pages_have_blocks():
    assert {p for p in PAGES if blocks(p)} >= {"README.md", "docs/your-own-hierarchy.md"}


# PettingZoo's api_test recommends Box / Discrete observations; Dict ones are the design here
@pytest.mark.filterwarnings("ignore::UserWarning:pettingzoo.*")
@pytest.mark.parametrize("page", [p for p in PAGES if blocks(p)])
def test_the_page_s_blocks_run_as_written(page, tmp_path, monkeypatch):
    if page in NEEDS and importlib.util.find_spec(NEEDS[page]) is None:
        pytest.skip(f"{page} needs the optional {NEEDS[page]!r}")
    script = "\n".join(blocks(page))
    for old, new in SMALLER.get(page, {}).items():
        assert old in script, f"{page} changed: update SMALLER in this test ({old})"
        script = script.replace(old, new)
    script = script.replace("TrainConfig(", "TrainConfig(progress=False, eval_max_steps=100, ")
    monkeypatch.chdir(tmp_path)
    exec(compile(script, page, "exec"), {"__name__": "__docs__"})
