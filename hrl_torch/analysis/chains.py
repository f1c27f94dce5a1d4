"""Finite Markov chains and flat MDPs: gains and relative value iteration (float64)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import torch
from tensordict import TensorDict

F64 = torch.float64


@dataclass(frozen=True)
class SolverOptions:
    """Iteration settings shared by the solvers.

    Attributes:
        tau: aperiodicity transform ``h + tau (T h - h)`` of relative value iteration.
        tol: stop when the span of ``T h - h`` (value iteration: the change) is below this.
        max_iter: give up (``RuntimeError``) after this many sweeps.
    """

    tau: float = 0.5
    tol: float = 1e-10
    max_iter: int = 100_000


DEFAULT_OPTIONS = SolverOptions()


@dataclass
class FiniteModel:
    """A finite MDP as tables: ``transition [S, A, S]``, ``reward [S, A]``, ``observations [S]``."""

    transition: torch.Tensor
    reward: torch.Tensor
    observations: TensorDict

    @classmethod
    def from_tables(cls, transition, reward, decode: Callable) -> FiniteModel:
        """Build from ``[S, A]`` next states (deterministic) or ``[S, A, S]`` probabilities.

        ``decode(states [S]) -> dict`` gives the observation fields the graph reads.
        """
        if transition.dtype == torch.long:
            transition = torch.nn.functional.one_hot(transition, transition.shape[0])
        n = transition.shape[0]
        obs = TensorDict(decode(torch.arange(n)), batch_size=[n])
        return cls(transition.to(F64), reward.to(F64), obs)

    @property
    def n_states(self) -> int:
        """Number of full states ``S``."""
        return self.transition.shape[0]

    def with_reward(self, reward: torch.Tensor) -> FiniteModel:
        """The same dynamics with another reward table (e.g. throughput weights)."""
        return replace(self, reward=reward.to(F64))


# --------------------------------------------------------------------------- Markov chains
@dataclass
class ChainGain:
    """Gains of a Markov chain.

    Attributes:
        gain: ``[N]`` gain from every state.
        recurrent_class: ``[N]`` class of every recurrent state, -1 for transient ones.
        class_gain: ``[C]`` gain of every recurrent class.
    """

    gain: torch.Tensor
    recurrent_class: torch.Tensor
    class_gain: torch.Tensor


def markov_chain_gain(transition: torch.Tensor, reward: torch.Tensor) -> ChainGain:
    """Gain ``P* r`` of a finite chain ``transition [N, N]``, ``reward [N]`` (Eq. 4.1)."""
    p, r = transition.to(F64), reward.to(F64)
    n = p.shape[0]
    reach = (p > 0) | torch.eye(n, dtype=torch.bool)
    while True:  # transitive closure by squaring
        wider = (reach.float() @ reach.float()) > 0
        if torch.equal(wider, reach):
            break
        reach = wider
    recurrent = ~(reach & ~reach.T).any(1)  # every state it reaches reaches it back
    rep = reach.float().argmax(1)  # smallest reachable index: the class of a recurrent state
    reps = torch.unique(rep[recurrent])
    label = torch.where(recurrent, torch.searchsorted(reps, rep), -1)
    rec = recurrent.nonzero().squeeze(1)
    # stationary distributions of all classes at once: pi (I - P) = 0, one sum-to-1 per class
    a = torch.eye(len(rec), dtype=F64) - p[rec][:, rec].T
    b = torch.zeros(len(rec), dtype=F64)
    first = torch.searchsorted(rec, reps)
    a[first] = (label[rec][None, :] == torch.arange(len(reps))[:, None]).to(F64)
    b[first] = 1.0
    pi = torch.linalg.solve(a, b)
    class_gain = torch.zeros(len(reps), dtype=F64).index_add_(0, label[rec], pi * r[rec])
    gain = torch.zeros(n, dtype=F64)
    gain[rec] = class_gain[label[rec]]
    tr = (~recurrent).nonzero().squeeze(1)
    if len(tr):  # transient states: absorption into the classes
        rhs = p[tr][:, rec] @ gain[rec]
        gain[tr] = torch.linalg.solve(torch.eye(len(tr), dtype=F64) - p[tr][:, tr], rhs)
    return ChainGain(gain, label, class_gain)


def first_best(q: torch.Tensor, ok: torch.Tensor, dim: int, tol: float):
    """Max over ``dim`` of ``q`` where ``ok`` and the first index within ``tol`` of it."""
    q = q.masked_fill(~ok, -torch.inf)
    best = q.amax(dim)
    return best, (q >= best.unsqueeze(dim) - tol).to(F64).argmax(dim)


def rvi(bellman, h: torch.Tensor, live: torch.Tensor, opt: SolverOptions):
    """Relative value iteration with the aperiodicity transform ``h + tau (T h - h)``.

    ``bellman(h)`` returns ``(T h, ...)``. Returns ``(h, bellman(h), (lo, hi))`` where
    ``lo <= g* <= hi`` are the span bounds ``min / max (T h - h)`` over the live states
    (Puterman 1994, Theorem 8.5.5).
    """
    ref = int(live.flatten().nonzero()[0])
    for _ in range(opt.max_iter):
        out = bellman(h)
        diff = (out[0] - h)[live]
        lo, hi = float(diff.min()), float(diff.max())
        if hi - lo <= opt.tol:
            return h, out, (lo, hi)
        h = h + opt.tau * (out[0] - h)
        h = torch.where(live, h - h.flatten()[ref], 0.0)
    raise RuntimeError(
        f"relative value iteration: span {hi - lo:.3g} > {opt.tol} after "
        f"{opt.max_iter} sweeps (is the optimal gain the same from every state?)"
    )


@dataclass
class FlatResult:
    """Optimal gain (``gain``, within ``gain_bounds``), bias ``[S]`` and greedy policy ``[S]``."""

    gain: float
    gain_bounds: tuple[float, float]
    bias: torch.Tensor
    policy: torch.Tensor


def table_rvi(p, r, ok, live, opt: SolverOptions) -> FlatResult:
    """RVI on ``p [S, C, S]``, ``r [S, C]`` with the choices ``ok [S, C]``."""

    def bellman(h):
        return first_best(r + torch.einsum("sct,t->sc", p, h), ok, 1, 1e-9)

    h, (_, policy), (lo, hi) = rvi(bellman, torch.zeros(p.shape[0], dtype=F64), live, opt)
    return FlatResult((lo + hi) / 2, (lo, hi), h, policy)


def flat_optimal(model: FiniteModel, options: SolverOptions = SolverOptions()) -> FlatResult:
    """Best gain of the flat MDP over stationary policies (communicating models)."""
    ok = torch.ones(model.reward.shape, dtype=torch.bool)
    live = torch.ones(model.n_states, dtype=torch.bool)
    return table_rvi(model.transition, model.reward, ok, live, options)


# --------------------------------------------------------------------------- the unrolled hierarchy
