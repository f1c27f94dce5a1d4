"""One server, two queues: a small event-driven continuing task (an SMDP) with an exact gain.

Jobs arrive at queue ``k`` as a Poisson process of rate ``RATES[k]``; each queue holds at most
``CAPACITY`` jobs (an arrival at a full queue is lost). The server stands at one queue and
chooses, whenever its last action ended: ``Serve`` a job of the queue it stands at (the job
leaves the queue at once; the service lasts ``SERVICE[k]`` times a factor 0.5, 1 or 1.5 drawn
uniformly, and pays ``PAY[k]`` when it ends), ``Switch`` to the other queue (``SWITCH_TIME``),
or ``Wait`` (``WAIT_TIME``). ``Serve`` at an empty queue waits. Reward per unit of time
(the gain) is what counts. Queue 1's jobs pay more per unit of service (2.5 against 1), but
switching costs time and queue 0's jobs arrive more often: when to leave a queue is the choice.

``exact_model`` is the SMDP over (server's queue, both queue lengths): 50 states, transition
probabilities, expected rewards and durations, exact (truncated Poisson arrivals over each
duration). ``gain`` gives a policy's exact gain or the optimal one (relative value iteration
on Schweitzer's transformation of the SMDP).
"""

from __future__ import annotations

import math

import torch

from hrl_torch.common.devices import constant_on
from hrl_torch.env.batched import BatchedEnv

CAPACITY = 4
RATES = (0.5, 0.2)
SERVICE = (1.0, 2.0)
PAY = (1.0, 5.0)
FACTORS = (0.5, 1.0, 1.5)
SWITCH_TIME = 1.5
WAIT_TIME = 0.5
SERVE, SWITCH, WAIT = 0, 1, 2
N_STATES = 2 * (CAPACITY + 1) ** 2
_SERVICE = torch.tensor(SERVICE)
_PAY = torch.tensor(PAY)
_FACTORS = torch.tensor(FACTORS)
_RATES = torch.tensor(RATES)


class PollingEnv(BatchedEnv):
    """``where [B]`` (the server's queue), ``queue [B, 2]`` lengths; continuous time."""

    state_keys = ("where", "queue", "served")
    observation_sizes = {
        "where": 2,
        "q0": CAPACITY + 1,
        "q1": CAPACITY + 1,
        "served": 3,
        "state": N_STATES,
    }

    def __init__(self, seeds, envs_per_learner, max_episode_steps=None, device="cpu"):
        super().__init__(seeds, envs_per_learner, 3, max_episode_steps, device)
        self.where = torch.zeros(self.batch_size, dtype=torch.long, device=self.device)
        self.queue = torch.zeros(self.batch_size, 2, dtype=torch.long, device=self.device)
        self.served = torch.zeros(self.batch_size, dtype=torch.long, device=self.device)

    def _reset_rows(self, mask):  # empty queues, server at queue 0
        self.where = self.where.masked_fill(mask, 0)
        self.queue = self.queue.masked_fill(mask[:, None], 0)
        self.served = self.served.masked_fill(mask, 0)

    def _step_all(self, action):
        factor = constant_on(_FACTORS, action.device)[self.rng.integers(len(FACTORS))]
        arrive_u = self.rng.uniform(2)  # (drawn for every row)
        here = self.queue.gather(1, self.where[:, None]).squeeze(1)
        serve = (action == SERVE) & (here > 0)
        service = constant_on(_SERVICE, action.device)[self.where] * factor
        duration = torch.where(
            serve, service, torch.where(action == SWITCH, SWITCH_TIME, WAIT_TIME)
        )
        left = torch.zeros_like(self.queue).scatter_(1, self.where[:, None], serve.long()[:, None])
        queue = self.queue - left
        arrivals = poisson_inverse(arrive_u, duration[:, None] * constant_on(_RATES, action.device))
        self.queue = (queue + arrivals).clamp_max(CAPACITY)
        reward = torch.where(serve, constant_on(_PAY, action.device)[self.where], 0.0)
        self.served = torch.where(serve, self.where + 1, 0)
        self.where = torch.where(action == SWITCH, 1 - self.where, self.where)
        return reward, duration, torch.zeros_like(serve)

    def _observe(self):
        q0, q1 = self.queue[:, 0], self.queue[:, 1]
        return {
            "where": self.where.clone(),
            "q0": q0.clone(),
            "q1": q1.clone(),
            "served": self.served.clone(),
            "state": encode(self.where, q0, q1),
        }


def poisson_inverse(u: torch.Tensor, mean: torch.Tensor) -> torch.Tensor:
    """Poisson(``mean``) draws by inversion of uniforms ``u``, cut at ``CAPACITY``."""
    n = torch.arange(CAPACITY, device=u.device)
    log_fact = torch.lgamma(n + 1.0)
    pmf = torch.exp(-mean[..., None] + n * torch.log(mean[..., None]) - log_fact)
    cdf = pmf.cumsum(-1)
    return (u[..., None] > cdf).sum(-1)


def encode(where, q0, q1):
    """State index ``(where * (C + 1) + q0) * (C + 1) + q1``."""
    return (where * (CAPACITY + 1) + q0) * (CAPACITY + 1) + q1


def _arrivals(mean: float) -> list[float]:
    """``P(N = n)`` for ``n < CAPACITY`` and ``P(N >= CAPACITY)``: Poisson(``mean``) cut."""
    p = [math.exp(-mean) * mean**n / math.factorial(n) for n in range(CAPACITY)]
    return [*p, 1.0 - sum(p)]


def _after(q: int, k: int, duration: float) -> list[float]:
    """Distribution of queue ``k``'s length after ``duration`` from length ``q``."""
    out = [0.0] * (CAPACITY + 1)
    for n, p in enumerate(_arrivals(RATES[k] * duration)):
        out[min(CAPACITY, q + n)] += p
    return out


def exact_model(gamma: float = 1.0):
    """``(P [S, 3, S], reward [S, 3], tau [S, 3])`` float64: the SMDP of the env, exactly.

    With ``gamma < 1``, ``P`` holds ``E[gamma^tau; s']`` instead (the discounted model: the
    values of the discounted learners' SMDP, ``V = max_a r + P V``).
    """
    c = CAPACITY + 1
    P = torch.zeros(N_STATES, 3, N_STATES, dtype=torch.float64)
    reward = torch.zeros(N_STATES, 3, dtype=torch.float64)
    tau = torch.zeros(N_STATES, 3, dtype=torch.float64)
    for s in range(N_STATES):
        where, q = s // (c * c), [s // c % c, s % c]
        for a in range(3):
            serve = a == SERVE and q[where] > 0
            if serve:
                outcomes = [(SERVICE[where] * f, 1.0 / len(FACTORS)) for f in FACTORS]
            else:
                outcomes = [(SWITCH_TIME if a == SWITCH else WAIT_TIME, 1.0)]
            start = list(q)
            start[where] -= int(serve)
            new_where = 1 - where if a == SWITCH else where
            for d, pd in outcomes:
                p0, p1 = _after(start[0], 0, d), _after(start[1], 1, d)
                for i in range(c):
                    for j in range(c):
                        P[s, a, (new_where * c + i) * c + j] += pd * gamma**d * p0[i] * p1[j]
                tau[s, a] += pd * d
            reward[s, a] = PAY[where] if serve else 0.0
    return P, reward, tau


def discounted_policy(gamma: float, tol: float = 1e-12) -> torch.Tensor:
    """The discount-optimal flat policy ``[S]`` for ``gamma`` per unit of time.

    A discounted learner's target for a primitive step is ``r + gamma^tau V(s')``: the step's
    reward undiscounted, the next state's value discounted by the step's duration.
    """
    P, r, _ = exact_model(gamma)
    v = torch.zeros(N_STATES, dtype=torch.float64)
    for _ in range(100_000):
        new = (r + P @ v).amax(1)
        if float((new - v).abs().max()) < tol:
            return (r + P @ new).argmax(1)
        v = new
    raise RuntimeError("value iteration did not converge")


def gain(P, reward, tau, policy=None, tol: float = 1e-12, max_iter: int = 200_000) -> float:
    """Exact gain per unit of time of ``policy [S]`` (``None``: the optimal gain).

    ``P [S, A, S]``, ``reward [S, A]`` (expected, per decision), ``tau [S, A]`` (expected
    duration). Schweitzer's data transformation (``eta < min tau``: ``r / tau``, ``eta / tau
    (P - I) + I``) makes an MDP with the same gain; relative value iteration solves it.
    Actions with ``reward = -inf`` are not allowed.
    """
    if policy is not None:
        s = torch.arange(P.shape[0])
        P, reward, tau = P[s, policy][:, None], reward[s, policy][:, None], tau[s, policy][:, None]
    eta = 0.9 * float(tau.min())
    eye = torch.eye(P.shape[0], dtype=P.dtype)[:, None]
    Pt = (eta / tau)[..., None] * (P - eye) + eye
    rt = reward / tau
    h = torch.zeros(P.shape[0], dtype=torch.float64)
    for _ in range(max_iter):
        q = rt + Pt @ h
        t = q.amax(1)
        new = t - t[0]
        if float((new - h).abs().max()) < tol:
            return float(t[0] - h[0])
        h = new
    raise RuntimeError("relative value iteration did not converge")


def states():
    """``(where, q0, q1)`` of every state ``[S]`` each."""
    s, c = torch.arange(N_STATES), CAPACITY + 1
    return s // (c * c), s // c % c, s % c


def priority_rule() -> torch.Tensor:
    """The c-mu rule per state ``[S]``: serve queue 1 when it has a job, else queue 0, else wait.

    Serving at the other queue starts with Switch.
    """
    where, q0, q1 = states()
    target = torch.where(q1 > 0, 1, torch.where(q0 > 0, 0, -1))
    return torch.where(target < 0, WAIT, torch.where(target == where, SERVE, SWITCH))


def exhaustive_rule() -> torch.Tensor:
    """Exhaustive polling: serve here while jobs wait, else switch if the other queue has one."""
    where, q0, q1 = states()
    here = torch.where(where == 0, q0, q1)
    other = torch.where(where == 0, q1, q0)
    return torch.where(here > 0, SERVE, torch.where(other > 0, SWITCH, WAIT))


def hierarchy_model():
    """The root's SMDP of the hierarchy ``Root -> Serve0, Serve1, Wait``: ``(P, reward, tau)``.

    ``Serve_k`` at queue ``k`` serves one job; elsewhere it switches and then serves (the job
    is still there: only the server takes jobs). Choices: 0 ``Serve0``, 1 ``Serve1``, 2
    ``Wait``; ``Serve_k`` at an empty queue ``k`` is not allowed (``reward -inf``).
    """
    P, reward, tau = exact_model()
    where, q0, q1 = states()
    Ph = torch.zeros(N_STATES, 3, N_STATES, dtype=torch.float64)
    rh = torch.zeros(N_STATES, 3, dtype=torch.float64)
    th = torch.zeros(N_STATES, 3, dtype=torch.float64)
    for k, qk in enumerate((q0, q1)):
        here = where == k
        # elsewhere: Switch, then Serve from wherever the switch ended (all at queue k)
        Ph[:, k] = torch.where(here[:, None], P[:, SERVE], P[:, SWITCH] @ P[:, SERVE])
        th[:, k] = torch.where(here, tau[:, SERVE], tau[:, SWITCH] + SERVICE[k])
        rh[:, k] = torch.where(qk > 0, PAY[k], -torch.inf)
    Ph[:, 2], rh[:, 2], th[:, 2] = P[:, WAIT], reward[:, WAIT], tau[:, WAIT]
    return Ph, rh, th


def hierarchy_rule(policy: torch.Tensor) -> torch.Tensor:
    """A flat policy ``[S]`` (Serve/Switch/Wait) as the root's choices (0/1 Serve_k, 2 Wait)."""
    where, q0, q1 = states()
    empty = torch.where(where == 0, q0, q1) == 0  # (Serve at an empty queue waits)
    wait = (policy == WAIT) | ((policy == SERVE) & empty)
    return torch.where(wait, 2, torch.where(policy == SERVE, where, 1 - where))
