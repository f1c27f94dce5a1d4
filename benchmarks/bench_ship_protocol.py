"""Ship steering hybrid, the full protocol: this checkout against a reference commit, in turn.

    .venv/bin/python benchmarks/bench_ship_protocol.py [--reference 1ce5127] [--episodes 50000]

Runs ``scripts/fig_5_7_to_5_12_ship.py --algos hybrid`` (5 seeds, the collector path, until
every seed has finished ``--episodes`` training episodes) twice in this process's venv, one
after the other: first on the reference commit (checked out into a temporary git worktree and
put first on ``PYTHONPATH``), then on this checkout. Prints a markdown table: wall-clock,
env steps and env steps/s of each, and their ratio. Each run writes its results to a
temporary folder (removed afterwards). Set-up aside, it takes about as long as the two runs
(several minutes each on two cores).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def run(repo: Path, out: Path, episodes: int, seeds: int) -> dict:
    """One protocol run of ``repo``'s code; the script's ``hybrid.json``."""
    env = dict(os.environ, PYTHONPATH=str(repo), RL_LOGGING_LEVEL="WARNING")
    cmd = [
        sys.executable,
        str(repo / "scripts" / "fig_5_7_to_5_12_ship.py"),
        "--algos",
        "hybrid",
        "--episodes",
        str(episodes),
        "--seeds",
        str(seeds),
        "--out",
        str(out),
    ]
    print(f"running {repo} ...", file=sys.stderr, flush=True)
    subprocess.run(cmd, cwd=repo, env=env, check=True, stdout=sys.stderr)
    return json.loads((out / "hybrid.json").read_text())


def gate_successes(result: dict) -> str:
    """Gate successes per 1000 episodes in the last block, ``mean (min-max)`` over seeds.

    The figure script's table column, from its ``hybrid.json``.
    """
    sys.path.insert(0, str(ROOT / "scripts"))
    from fig_5_7_to_5_12_ship import _stat

    curves = result["curves"]
    last = min(result["episodes_per_seed"]) // curves["episodes_per_block"] - 1
    return _stat(curves["gate_successes"], 0, last)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--reference", default="1ce5127", help="commit to compare against")
    parser.add_argument("--episodes", type=int, default=50_000)
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ref = tmp / "reference"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(ref), args.reference],
            cwd=ROOT,
            check=True,
            capture_output=True,
        )
        try:
            rows = [
                (
                    f"reference `{args.reference}`",
                    run(ref, tmp / "out-ref", args.episodes, args.seeds),
                ),
                ("this checkout", run(ROOT, tmp / "out-new", args.episodes, args.seeds)),
            ]
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(ref)], cwd=ROOT)
    head = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    print(f"# Ship hybrid, full protocol ({args.seeds} seeds x {args.episodes:,} episodes)\n")
    print(f"This checkout: `{head}`; load average at the end {os.getloadavg()}.\n")
    print(
        "| code | wall s | env steps | env steps/s | episodes per seed (min) "
        "| gate successes, last 1000 episodes |"
    )
    print("|---|---:|---:|---:|---:|---|")
    for name, r in rows:
        print(
            f"| {name} | {r['wall_seconds']:.0f} | {r['env_steps']:,} | "
            f"{r['env_steps_per_second']:,.0f} | {min(r['episodes_per_seed']):,} | "
            f"{gate_successes(r)} |"
        )
    (_, old), (_, new) = rows
    print(
        f"\nWall-clock ratio (reference / this checkout): "
        f"**{old['wall_seconds'] / new['wall_seconds']:.2f}x**; env steps/s ratio "
        f"{new['env_steps_per_second'] / old['env_steps_per_second']:.2f}x."
    )


if __name__ == "__main__":
    main()
