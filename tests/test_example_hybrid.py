"""docs/your-own-hybrid.md: the page's blocks, run as written, learn the task.

The page's code runs in one namespace, as ``tests/test_docs_blocks.py`` runs it (there at a
budget too small to learn). ``test_the_page_s_hybrid_learns`` runs it at the page's own budget
(3 seeds x 40,000 env steps; about 100 s at load 9 on 2 cores): only learning passes, since the
untrained greedy hybrid heads east from every start and most episodes run into the 200-step
limit (``test_the_page_runs_and_starts_untrained``).
"""

from __future__ import annotations

import pytest

from tests.test_docs_blocks import blocks

PAGE = "docs/your-own-hybrid.md"
AS_WRITTEN = "seeds, steps = [0, 1, 2], 40_000"


def run_page(steps: int | None = None, seeds: str = "[0, 1, 2]") -> dict:
    """The page's namespace after its blocks ran (``steps``: another budget)."""
    script = "\n".join(blocks(PAGE))
    assert AS_WRITTEN in script, f"{PAGE} changed: update this test"
    if steps is not None:
        script = script.replace(AS_WRITTEN, f"seeds, steps = {seeds}, {steps}")
    script = script.replace("TrainConfig(", "TrainConfig(progress=False, ")
    space = {"__name__": "__docs__"}
    exec(compile(script, PAGE, "exec"), space)
    return space


@pytest.mark.slow  # (11 s: the fast check is tests/test_docs_blocks.py, the page at 1,000 steps)
def test_the_page_runs_and_starts_untrained():
    space = run_page(16, "[0]")
    truncated = space["records"]["truncated"].float().mean().item()
    assert truncated > 0.5, truncated  # (what the learning test must overcome)
    assert abs(space["reference"] - 14.72) < 0.01  # (the page: the rule's steps)


@pytest.mark.slow
def test_the_page_s_hybrid_learns():
    space = run_page()
    records, share = space["records"], space["reference"] / space["length"]
    assert not bool(records["truncated"].any()), "a greedy episode hit the step limit"
    assert bool((share >= 0.6).all()), share.tolist()  # (untrained: about 0.07)
