"""The registered ``(domain, algo)`` pairs that the every-configuration tests run in `make test`.

``tests/test_resume_every_algorithm.py`` and ``tests/test_any_device.py`` read their cases from
the registry, so every newly registered pair is covered. The pairs of ``SLOW_PAIRS`` run only in
``make test-all`` (``-m slow``): each differs from a pair the fast suite runs only in a constant
(the same code), or is the costliest of its learner while that learner also runs in the fast
suite on a cheaper domain and the same env runs there with the other learners.
"""

from __future__ import annotations

import pytest

_SAME_CODE_AS_COM_1 = "COM-Cooperative HRL as com-1, another ComCost value only"
_SAME_CODE_AS_LOSS50 = "COM-Cooperative HRL as com-0-loss50, another loss probability only"
_SAME_CODE_AS_1S = (
    "as the pair without -2s, other primitive durations only (Figure 6.5's timing; the timing "
    "option runs fast with four-agv selfish-2s)"
)
_SAME_CODE_AS_DISCRETE = (
    "as the agv pair, continuous time only (the same learner and env with continuous=True): "
    "agv-ct har runs fast, and continuous time with unit durations equals discrete time "
    "exactly in tests/learners/test_average_reward.py"
)
_SAME_CODE_AS_SINGLE = (
    "single with buffer capacity 1, a constant of the env and graph (capacity 1 runs fast "
    "with four-agv-earlier q)"
)
_SAME_CODE_AS_TWO_TAXI = (
    "as the two-taxi pair, footnote 4's arrivals read per station only (make_text_env's "
    "arrivals option: the same graph, learner and env code; two-taxi-station single runs fast)"
)
_SAME_RULE_CODE = (
    "another DispatchRule's keys: they run fast wrapped per AGV on four-agv, and the "
    "centralised claims with four-agv-earlier fcfs"
)
_COSTLY_COOPERATIVE = (
    "the slowest case of its test; Cooperative HRL runs fast on four-agv-earlier, the text env "
    "with "
    "the selfish and single learners"
)

#: (domain, algo) -> why it runs only in `make test-all`
SLOW_PAIRS: dict[tuple[str, str], str] = {
    **{
        (domain, f"com-{cost}"): _SAME_CODE_AS_COM_1
        for domain in ("two-taxi-earlier", "two-taxi", "two-taxi-station")
        for cost in (0, 5, 10)  # (ComCost 0 also runs fast in com-0-loss50)
    },
    **{
        (domain, "com-0-loss100"): _SAME_CODE_AS_LOSS50
        for domain in ("two-taxi-earlier", "two-taxi", "two-taxi-station")
    },
    **{
        ("four-agv", f"{algo}-2s"): _SAME_CODE_AS_1S
        for algo in ("single", "fcfs", "hqf", "nsf")
    },
    ("four-agv-earlier", "selfish-2s"): _SAME_CODE_AS_1S,
    ("four-agv-earlier", "cooperative-2s"): _SAME_CODE_AS_1S,
    ("four-agv-earlier", "single-c1"): _SAME_CODE_AS_SINGLE,
    ("four-agv-earlier", "hqf"): _SAME_RULE_CODE,
    ("four-agv-earlier", "nsf"): _SAME_RULE_CODE,
    **{("agv-ct", algo): _SAME_CODE_AS_DISCRETE for algo in ("rar", "hdr", "rvi-q")},
    **{
        ("two-taxi-station", algo): _SAME_CODE_AS_TWO_TAXI
        for algo in ("selfish", "cooperative", "com-1", "com-0-loss50")
    },
    ("four-agv", "cooperative"): _COSTLY_COOPERATIVE,
    ("four-agv", "cooperative-2s"): _COSTLY_COOPERATIVE,
}


def pair_param(domain: str, algo: str, *marks, id: str | None = None):  # noqa: A002
    """``pytest.param(domain, algo)``, marked ``slow`` if the pair is in ``SLOW_PAIRS``."""
    if (domain, algo) in SLOW_PAIRS:
        marks = (*marks, pytest.mark.slow)
    return pytest.param(domain, algo, marks=marks, id=id)


def pair_params(pairs) -> list:
    """``pair_param`` of each ``(domain, algo)``."""
    return [pair_param(domain, algo) for domain, algo in pairs]
