"""Every table and figure of docs/reproduction.md, from scratch, in one command.

    python scripts/reproduce_all.py                # the whole reproduction (many hours here)
    python scripts/reproduce_all.py --quick        # a smoke run of every part (minutes)
    python scripts/reproduce_all.py --dry-run      # list the parts and their commands
    python scripts/reproduce_all.py --only taxi trash --quick

(``make reproduce`` / ``make reproduce-quick``.) Each part is one of the figure scripts in
``scripts/``, run in its own process with its output folder under ``--out`` (default
``runs/reproduce`` or ``runs/reproduce-quick``). What a script prints (its markdown tables) is
kept in ``<out>/<part>.md``; ``<out>/times.md`` lists every part with its command, its wall
time and whether it finished. ``--quick`` runs each part on one or two seeds and a few
thousand steps: it checks that the pipeline runs end to end, not the numbers.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Part:
    """One section of docs/reproduction.md and the script run that regenerates it.

    Attributes:
        name: short name (``--only``).
        section: the heading of docs/reproduction.md it fills.
        script: the script in ``scripts/``.
        full: its arguments for the documented run.
        quick: its arguments for a smoke run.
        out_flag: how the script takes its output folder (``None``: it has none; it writes
            under ``runs/`` of the working folder, which is ``--out``).
    """

    name: str
    section: str
    script: str
    full: tuple[str, ...]
    quick: tuple[str, ...]
    out_flag: str | None = "--out"


PARTS = (
    Part("taxi", "Taxi", "taxi_maxq_vs_q.py", (), ("--seeds", "2", "--algos", "maxq-q")),
    Part(
        "taxi-relapse",
        "The relapse into wall-bumping loops",
        "taxi_relapse.py",
        (),
        ("--seeds", "2", "--steps", "4000", "--envs", "4"),
        None,
    ),
    Part(
        "fig-4-3",
        "Figure 4.3: small AGV",
        "fig_4_3_small_agv.py",
        (),
        ("--seeds", "2", "--steps", "2000"),
    ),
    Part(
        "fig-4-6",
        "Figures 4.6 and 4.7 (discrete time)",
        "fig_4_6_agv_dt.py",
        (),
        ("--seeds", "1", "--steps", "2000", "--flat-steps", "2000"),
    ),
    Part(
        "fig-4-7",
        "Figures 4.6 and 4.7 (continuous time)",
        "fig_4_7_agv_ct.py",
        (),
        ("--seeds", "1", "--steps", "2000", "--flat-steps", "2000"),
    ),
    Part(
        "fig-5-3",
        "Taxi-fuel: HPGRL, MAXQ-Q and flat Q-learning (Figure 5.3)",
        "fig_5_3_taxi_fuel.py",
        (),
        ("--seeds", "1", "--steps", "3000"),
    ),
    Part(
        "fig-5-3-text",
        "The text's reading: 8,750 states (taxi-fuel)",
        "fig_5_3_taxi_fuel_text.py",
        (),
        ("--seeds", "1", "--steps", "3000", "--algos", "maxq-q"),
    ),
    Part(
        "ship",
        "Ship steering: the hierarchical hybrid (Figures 5.7-5.12)",
        "fig_5_7_to_5_12_ship.py",
        ("--algos", "hybrid", "flat-pg", "actor-critic"),
        ("--algos", "hybrid", "--seeds", "1", "--episodes", "64", "--envs", "8"),
    ),
    Part(
        "four-agv-earlier",
        "Four-AGV scheduling (Figures 6.4-6.8), four-agv",
        "fig_6_4_to_6_8_agv.py",
        ("--variant", "text"),
        ("--variant", "text", "--only", "fig_6_5", "--seeds", "1", "--steps", "1000"),
    ),
    Part(
        "trash",
        "Trash collection: exact gains of the learned joint policies",
        "trash_exact.py",
        ("--seeds", "5", "--steps", "150000"),
        ("--seeds", "1", "--steps", "3000"),
    ),
    Part(
        "two-taxi-earlier",
        "Two taxis: Cooperative and COM-Cooperative HRL (Figures 6.11-6.14)",
        "fig_6_11_to_6_14_two_taxi.py",
        ("--eval-every", "50000"),
        ("--seeds", "2", "--steps", "2000", "--only", "fig_6_11"),  # (it needs 2 seeds)
    ),
)


def command(part: Part, quick: bool, out: Path) -> list[str]:
    """The command line of ``part`` (its output under ``out / part.name``)."""
    args = list(part.quick if quick else part.full)
    if part.out_flag is not None:
        args += [part.out_flag, str(out / part.name)]
    return [sys.executable, str(ROOT / "scripts" / part.script), *args]


def run_part(part: Part, quick: bool, out: Path) -> tuple[float, int]:
    """Run one part; its output goes to ``out / f"{part.name}.md"``. ``(seconds, exit code)``."""
    cmd = command(part, quick, out)
    cwd = out / part.name
    cwd.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "RL_LOGGING_LEVEL": "WARNING"}
    start = time.perf_counter()
    with open(out / f"{part.name}.md", "w") as log:
        done = subprocess.run(cmd, cwd=cwd, env=env, stdout=log, stderr=subprocess.STDOUT)
    code = done.returncode
    return time.perf_counter() - start, code


def times_table(rows: list[tuple[Part, list[str], float, int]], quick: bool) -> str:
    """The ``times.md`` table: part, section, command, wall seconds, status."""
    mode = "--quick" if quick else "full"
    lines = [
        f"# reproduce_all.py ({mode}), {time.strftime('%Y-%m-%d %H:%M')}",
        "",
        "| part | section of docs/reproduction.md | command | wall s | status |",
        "|---|---|---|---:|---|",
    ]
    for part, cmd, seconds, code in rows:
        shown = " ".join(["scripts/" + part.script, *cmd[2:]])
        status = "ok" if code == 0 else f"exit {code}"
        lines.append(f"| {part.name} | {part.section} | `{shown}` | {seconds:.0f} | {status} |")
    total = sum(r[2] for r in rows)
    lines.append(f"| all | | | {total:.0f} | |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Run the chosen parts one after another; print each one's time."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run of every part")
    parser.add_argument("--dry-run", action="store_true", help="list the commands only")
    parser.add_argument("--only", nargs="+", choices=[p.name for p in PARTS], default=None)
    parser.add_argument("--out", default=None, help="default runs/reproduce[-quick]")
    args = parser.parse_args(argv)
    out = Path(args.out or ("runs/reproduce-quick" if args.quick else "runs/reproduce"))
    out = out.resolve()
    parts = [p for p in PARTS if args.only is None or p.name in args.only]
    if args.dry_run:
        for part in parts:
            print(f"{part.name}: {' '.join(command(part, args.quick, out)[1:])}")
        return 0
    rows, failed = [], 0
    for part in parts:
        print(f"{part.name}: {part.section} ...", flush=True)
        seconds, code = run_part(part, args.quick, out)
        failed += code != 0
        rows.append((part, command(part, args.quick, out), seconds, code))
        status = "ok" if code == 0 else f"FAILED (exit {code}; see {out / part.name}.md)"
        print(f"{part.name}: {seconds:.0f} s, {status}", flush=True)
        (out / "times.md").write_text(times_table(rows, args.quick))
    print(f"all: {sum(r[2] for r in rows):.0f} s; table in {out / 'times.md'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
