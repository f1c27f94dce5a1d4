"""The held-out tasks' references (issue 33, Build 6) and their envs against the exact models."""

from fractions import Fraction

import pytest
import torch

from envs.heldout import couriers, polling


def test_couriers_references():
    _, terminal, starts = couriers.exact_model()
    best = couriers.optimal_values()
    assert float(starts @ best) == pytest.approx(float(Fraction(-182, 27)))
    # the hierarchy with a root that sees the joint state loses nothing
    assert torch.equal(couriers.hierarchy_values(), best)
    # two couriers that each run the one-courier optimum lose 2.6 steps: coordination pays
    assert float(starts @ couriers.independent_values()) == pytest.approx(-757 / 81)
    assert float(best[starts > 0].min()) == -9.0


def test_couriers_env_follows_the_model():
    """The optimal joint policy played in the env earns the optimal value of each start."""
    nxt, _, _ = couriers.exact_model()
    best = couriers.optimal_values()
    policy = best[nxt].argmax(1)  # joint action a0 * 3 + a1
    env = couriers.CouriersEnv([3], 64)
    td = env.reset()
    state = couriers.encode(td["agents", "pos"], td["parcels"])
    expected, total = best[state], torch.zeros(64, dtype=torch.float64)
    done = torch.zeros(64, dtype=torch.bool)
    for _ in range(12):
        a = policy[couriers.encode(td["agents", "pos"], td["parcels"])]
        td = env.step(torch.stack([a // 3, a % 3], 1))
        total += torch.where(done, 0.0, td["reward"].double())
        done |= td["terminated"]
    assert done.all() and torch.equal(total, expected)


def test_polling_references():
    P, r, tau = polling.exact_model()
    assert torch.allclose(P.sum(-1), torch.ones(1, dtype=torch.float64))
    assert polling.gain(P, r, tau) == pytest.approx(1.35749, abs=1e-5)
    assert polling.gain(*polling.hierarchy_model()) == pytest.approx(1.35749, abs=1e-5)
    assert polling.gain(P, r, tau, polling.exhaustive_rule()) == pytest.approx(1.35064, abs=1e-5)
    assert polling.gain(P, r, tau, polling.priority_rule()) == pytest.approx(1.27794, abs=1e-5)
    # the discount-optimal policy at HDR's registered gamma (0.95 per unit of time)
    hdr = polling.hierarchy_rule(polling.discounted_policy(0.95))
    assert polling.gain(*polling.hierarchy_model(), hdr) == pytest.approx(1.33967, abs=1e-5)


@pytest.mark.parametrize(
    ("state", "action"), [(7, polling.SERVE), (33, polling.SERVE), (12, polling.SWITCH)]
)
def test_polling_env_transitions_match_the_model(state, action):
    """One step from a fixed state in 8,192 rows: next states as the model's ``P``."""
    P, r, tau = polling.exact_model()
    rows = 8192
    env = polling.PollingEnv([0], rows)
    env.reset()
    where, q0, q1 = (x[state] for x in polling.states())
    env.where = torch.full((rows,), int(where))
    env.queue = torch.tensor([int(q0), int(q1)]).repeat(rows, 1)
    td = env.step(torch.full((rows,), action))
    seen = torch.bincount(td["state"], minlength=polling.N_STATES).double() / rows
    assert float((seen - P[state, action]).abs().sum()) / 2 < 0.03  # total variation
    assert float(td["reward"].mean()) == pytest.approx(float(r[state, action]))
    assert float(td["duration"].mean()) == pytest.approx(float(tau[state, action]), rel=0.03)
