"""The mutation list tracks the code: a change that moves a mutant's snippet must re-point the
mutant in the same commit (``make mutate`` refuses to run otherwise, and it is not part of CI)."""

from pathlib import Path

from tests.mutants import MUTANTS

ROOT = Path(__file__).resolve().parents[1]


def test_every_mutant_snippet_occurs_once_in_its_file():
    stale = [
        f"{m.name}: {m.file} contains its snippet {count} times"
        for m in MUTANTS
        if (count := (ROOT / m.file).read_text().count(m.find)) != 1
    ]
    assert stale == [], "update tests/mutants.py:\n" + "\n".join(stale)


def test_mutant_names_are_unique_and_every_mutant_changes_its_snippet():
    names = [m.name for m in MUTANTS]
    assert len(names) == len(set(names))
    assert all(m.find != m.replace for m in MUTANTS)
