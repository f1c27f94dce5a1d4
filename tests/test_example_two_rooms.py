"""The worked example of docs/your-own-hierarchy.md runs and learns the optimal policy."""

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "example_two_rooms.py"


def load_example():
    spec = importlib.util.spec_from_file_location("example_two_rooms", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_example_learns_the_optimal_return():
    example = load_example()
    result = example.main(steps=20_000, seeds=(0, 1, 2), progress=False)
    # the evaluation episodes' optimal return: via the doorway (2, 4) to the goal (4, 8),
    # -1 per step and +10 instead of -1 on the last one
    cells = example.TwoRoomsEnv([123], 50).reset()["cell"]
    row, col = cells // 9, cells % 9
    n_steps = (row - 2).abs() + (4 - col) + 2 + 4
    optimal = float((11 - n_steps).float().mean())
    assert all(abs(v - optimal) < 1e-4 for v in result.final_eval), (result.final_eval, optimal)
