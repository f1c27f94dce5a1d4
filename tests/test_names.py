"""The dissertation's set-up has the plain name (0.2.0): no ``-text`` suffix, 0.1's names mapped.

0.1 named the text's set-ups ``four-agv-text``, ``two-taxi-text``, ``taxi-fuel-text`` and
``ship-steering --algo hybrid-text``; the plain names were earlier readings. From 0.2.0 the plain
names are the text's and the earlier readings are ``-earlier`` variants. A user's old ``-text``
name still works with a DeprecationWarning; a 0.1 run record is read with 0.1's names.
"""

import re
import warnings
from pathlib import Path

import pytest

import agents  # noqa: F401
from hrl_torch.runs import registry

ROOT = Path(__file__).resolve().parents[1]


def test_no_registered_name_needs_a_text_suffix():
    assert not [n for n in registry.names() if "text" in n]
    for name in registry.names():
        assert not [a for a in registry.get(name).algos if a.endswith("-text")], name


def test_the_readmes_domains_are_registered_and_the_texts():
    readme = (ROOT / "README.md").read_text()
    used = set(re.findall(r"hrl-torch (?:train|check) ([a-z][a-z-]*)", readme))
    assert used and used <= set(registry.names())
    assert not {n for n in used if n.endswith("-earlier")}
    assert "Section 6.4" in registry.get("four-agv").description
    assert "Section 5.3" in registry.get("ship-steering").description


@pytest.mark.parametrize(
    ("old", "new"),
    [
        (("four-agv-text", "cooperative"), ("four-agv", "cooperative")),
        (("two-taxi-text-station", "cooperative"), ("two-taxi-station", "cooperative")),
        (("ship-steering", "hybrid-text"), ("ship-steering", "hybrid")),
    ],
)
def test_an_old_text_name_still_works_with_a_deprecation_warning(old, new):
    with pytest.warns(DeprecationWarning, match=f"is {new[0]}"):
        assert registry.current_names(*old) == new
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert registry.current_names(*new) == new  # today's names: no warning


def test_a_deprecated_domain_name_gets_todays_spec():
    with pytest.warns(DeprecationWarning):
        assert registry.get("four-agv-text") is registry.get("four-agv")


@pytest.mark.parametrize(
    ("recorded", "today"),
    [
        (("four-agv", "cooperative-nav"), ("four-agv-earlier", "cooperative-nav")),
        (("four-agv-text", "cooperative"), ("four-agv", "cooperative")),
        (("two-taxi", "com-1"), ("two-taxi-earlier", "com-1")),
        (("taxi-fuel-text", "hpgrl"), ("taxi-fuel", "hpgrl")),
        (("ship-steering", "hybrid"), ("ship-steering-earlier", "hybrid")),
        (("ship-steering", "flat-pg-text"), ("ship-steering", "flat-pg")),
        (("taxi", "maxq-q"), ("taxi", "maxq-q")),
    ],
)
def test_a_0_1_run_record_is_read_with_0_1_names(recorded, today):
    assert registry.recorded_names(*recorded, version="0.1.0") == today
    domain, algo = today
    assert algo in registry.get(domain).algos
    assert registry.recorded_names(*today, version="0.2.0") == today  # today's records as they are
