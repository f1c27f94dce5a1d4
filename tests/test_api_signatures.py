"""The public API's signatures are pinned (scripts/api_reference.py, docs/api.md).

A changed constructor, function or public method of a name in ``PUBLIC`` fails here until the
change is made on purpose: ``python scripts/api_reference.py`` rewrites
``tests/api_signatures.json`` and ``docs/api.md``, and CHANGELOG.md says what changed (with a
``DeprecationWarning`` for the old form, README's deprecation policy).
"""

import importlib
import json

from scripts.api_reference import DOC, PIN, PUBLIC, names_of, signatures

REGENERATE = "python scripts/api_reference.py (and a CHANGELOG.md line)"


def test_the_public_signatures_are_the_pinned_ones():
    pinned, now = json.loads(PIN.read_text()), signatures()
    changed = [f"{k}: {pinned[k]} -> {now[k]}" for k in pinned if k in now and pinned[k] != now[k]]
    removed = sorted(set(pinned) - set(now))
    added = sorted(set(now) - set(pinned))
    assert not (changed or removed or added), (
        f"public API changed: changed {changed}, removed {removed}, added {added}; "
        f"if on purpose: {REGENERATE}"
    )


def test_every_public_name_is_in_the_reference_page():
    page = DOC.read_text()
    for module in PUBLIC:
        assert f"## `{module}`" in page, f"{module} missing from docs/api.md: {REGENERATE}"
        for name in names_of(module):
            assert f"- `{name}" in page, f"{module}.{name} missing from docs/api.md: {REGENERATE}"


def test_the_public_names_import_and_the_pin_sees_a_change(monkeypatch):
    for module in PUBLIC:
        mod = importlib.import_module(module)
        assert all(hasattr(mod, n) for n in names_of(module)), module
    import hrl_torch.runs.domain as domain

    def with_overrides(spec, overrides, unknown="cannot sweep", extra=None):  # a new argument
        return spec

    monkeypatch.setattr(domain, "with_overrides", with_overrides)
    now = signatures()["hrl_torch.runs.domain.with_overrides"]
    assert now != json.loads(PIN.read_text())["hrl_torch.runs.domain.with_overrides"]
