"""Mutation check: does the fast test suite catch one-line bugs in the core?

Each mutant in ``tests/mutants.py`` replaces one exact snippet of one file (learners,
executor, graph, tables, tiles, env base, checkpoint, the domain envs). For every mutant this
script copies the repository once into a scratch folder, applies the mutant there (the working
tree is never touched), and runs the fast suite (``-m "not slow"``), the mutant's ``first``
test files before the rest so that a killed mutant usually dies in seconds. A mutant is
*killed* when a test fails (or the run exceeds ``--timeout``); a *survivor* passes the whole
fast suite. ``--slow`` runs the slow learning checks against the survivors.

Usage::

    make mutate                                   # every mutant, fast suite
    .venv/bin/python scripts/mutate.py --only maxq-gamma-not-gamma-n --only smdp-sign
    .venv/bin/python scripts/mutate.py --list     # names and descriptions
    .venv/bin/python scripts/mutate.py --slow     # survivors also against the slow suite

The last line printed is ``N of M mutants killed``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.mutants import MUTANTS, Mutant  # noqa: E402


def check_snippets(mutants: list[Mutant]) -> None:
    """Every mutant's snippet must occur exactly once in its file (the list tracks the code)."""
    stale = []
    for m in mutants:
        text = (ROOT / m.file).read_text()
        if text.count(m.find) != 1:
            stale.append(f"{m.name}: {m.file} contains its snippet {text.count(m.find)} times")
    if stale:
        sys.exit("stale mutants (update tests/mutants.py):\n  " + "\n  ".join(stale))


def copy_repository(dest: Path) -> None:
    """The tracked and untracked (not ignored) files of the repository, into ``dest``."""
    listed = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "-z"],
        cwd=ROOT,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split("\0")
    for rel in filter(None, listed):
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


def run_pytest(copy: Path, args: list[str], timeout: float) -> tuple[bool, str]:
    """``(passed, last line)`` of a pytest run in ``copy``; a timeout counts as a failure."""
    env = {**os.environ, "PYTHONPATH": str(copy), "RL_LOGGING_LEVEL": "WARNING"}
    cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:randomly", *args]
    try:
        out = subprocess.run(
            cmd, cwd=copy, env=env, capture_output=True, text=True, timeout=timeout
        )
    except subprocess.TimeoutExpired:
        return False, f"timeout after {timeout:.0f} s"
    lines = [ln for ln in out.stdout.strip().splitlines() if ln.strip()]
    failed = [ln for ln in lines if ln.startswith(("FAILED", "ERROR"))]
    last = lines[-1] if lines else out.stderr.strip()[-200:]
    return out.returncode == 0, "; ".join([*failed[:1], last])


def run_mutant(
    m: Mutant, copy: Path, marker: str, workers: int, timeout: float, quick: bool = False
) -> str:
    """Apply ``m`` in ``copy``, run the suite and restore; the failing line, or ""."""
    target = copy / m.file
    original = target.read_text()
    target.write_text(original.replace(m.find, m.replace, 1))
    try:
        first = [f for f in m.first if (copy / f).exists()]
        if first:
            passed, line = run_pytest(copy, ["-m", marker, *first], timeout)
            if not passed or quick:
                return "" if passed else line
        parallel = ["-n", str(workers)] if workers > 1 else []
        passed, line = run_pytest(copy, ["-m", marker, *parallel], timeout)
        return "" if passed else line
    finally:
        target.write_text(original)


def main() -> int:
    """Run the mutants; print survivors and the kill count."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append", default=[], help="run this mutant (repeat)")
    parser.add_argument("--list", action="store_true", help="list the mutants and exit")
    parser.add_argument("--slow", action="store_true", help="run the slow suite on survivors")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="run only each mutant's first test files (a quick check while writing tests; "
        "the verdict needs the full run)",
    )
    parser.add_argument("--workers", type=int, default=2, help="pytest-xdist workers")
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds per suite run")
    args = parser.parse_args()
    chosen = [m for m in MUTANTS if not args.only or m.name in args.only]
    unknown = set(args.only) - {m.name for m in MUTANTS}
    if unknown:
        sys.exit(f"unknown mutants: {sorted(unknown)}")
    if args.list:
        for m in chosen:
            print(f"{m.name:40s} {m.file}: {m.why}")
        return 0
    check_snippets(chosen)
    survivors: list[Mutant] = []
    with tempfile.TemporaryDirectory(prefix="hrl-mutate-") as tmp:
        copy = Path(tmp)
        copy_repository(copy)
        parallel = ["-n", str(args.workers)] if args.workers > 1 else []
        if not args.quick:
            passed, line = run_pytest(copy, ["-m", "not slow", *parallel], args.timeout)
            if not passed:
                sys.exit(f"the fast suite fails without any mutant ({line}): fix it first")
        for k, m in enumerate(chosen, 1):
            start = time.perf_counter()
            failure = run_mutant(m, copy, "not slow", args.workers, args.timeout, args.quick)
            took = time.perf_counter() - start
            verdict = f"killed ({failure})" if failure else "SURVIVED"
            print(f"[{k}/{len(chosen)}] {m.name}: {verdict} [{took:.0f} s]", flush=True)
            if not failure:
                survivors.append(m)
        slow_killed = []
        if args.slow:
            for m in survivors:
                failure = run_mutant(m, copy, "slow", args.workers, args.timeout)
                print(f"[slow] {m.name}: {'killed' if failure else 'SURVIVED'} {failure}")
                if failure:
                    slow_killed.append(m)
    print("\nsurvivors of the fast suite:" if survivors else "\nno survivors")
    for m in survivors:
        slow = " (killed by the slow suite)" if m in slow_killed else ""
        print(f"  {m.name}: {m.file}: {m.why}{slow}")
    killed = len(chosen) - len(survivors)
    if args.slow:
        print(f"fast + slow suites: {killed + len(slow_killed)} of {len(chosen)} mutants killed")
    print(f"{killed} of {len(chosen)} mutants killed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
