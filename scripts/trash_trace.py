"""Trace Cooperative HRL on trash (issue 22): train one variant, print its exact gains.

Every variant starts from the setup of ``scripts/trash_exact.py`` with the completions of every
subtask starting at -10 (the setup before issue 22) and changes one thing or a few: the broadcast
rule, the root's initial completions, the step size, exploration, all-states updating, the
termination scheme, a team utility at the root, a second cooperation level, a per-entry 1/n
step size, Collect subtasks that know the other robot's ``U_1`` task. The rows of the trace
tables in ``docs/reproduction.md`` ("Trash collection") came from it::

    python scripts/trash_trace.py --broadcast simultaneous            # as before issue 22
    python scripts/trash_trace.py --root-init 0                       # the new default
    python scripts/trash_trace.py --root-init 0 --alpha lin:0.2:0.02 --steps 300000
    python scripts/trash_trace.py --algo selfish --alpha visits:0.2:0.01
    python scripts/trash_trace.py --root-init 0 --collect-u1
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import torch

from agents import trash as T
from agents.trash import visit_step_size
from envs.trash import DUMP_REWARD
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Subtask
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.modules.schedules import Linear
from hrl_torch.multiagent.cooperative import Cooperation, CooperativeSubtask, cooperation_levels
from hrl_torch.runs import registry
from hrl_torch.runs.experiment import RunOptions, build_trainer
from scripts.trash_exact import exact_gains


def _arguments() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--algo", default="cooperative", choices=("cooperative", "selfish"))
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--first-seed", type=int, default=0, help="the first seed")
    p.add_argument("--steps", type=int, default=150_000)
    p.add_argument(
        "--alpha", default="0.2", help="a number, lin:START:END over the run, or visits:HI:LO"
    )
    p.add_argument("--eps-frac", type=float, default=0.5, help="epsilon decays over this share")
    p.add_argument("--broadcast", default="sequential", choices=("sequential", "simultaneous"))
    p.add_argument("--scheme", default="continue", choices=("continue", "any", "all"))
    p.add_argument("--root-init", type=float, default=None, help="the root's initial C")
    p.add_argument("--visited", type=int, default=0, help="all-states updating, visits kept")
    p.add_argument("--team-root", action="store_true", help="others' dumps: root's internal r")
    p.add_argument("--two-levels", action="store_true", help="Collect subtasks cooperative too")
    p.add_argument("--shared-tables", action="store_true", help="both robots learn one table")
    p.add_argument("--collect-u1", action="store_true", help="CollectTk knows the other's U_1")
    return p.parse_args()


def _team_hierarchy() -> TaskGraph:
    """Figure 6.1 with the other robots' dumps (+20 each) as the root's internal reward."""
    root = Subtask(
        "Root",
        T.U1,
        n_states=T.ROOT_STATES,
        abstract=T._root_state,
        shaping_reward=lambda o, a, o2: DUMP_REWARD * (o2["n_dumped"] - o2["dumped"]).float(),
    )
    return TaskGraph("Root", [root, *T._collection_nodes()], n_actions=T.N_ACTIONS)


def collect_knows_u1(graph: TaskGraph, cooperation: Cooperation) -> TaskGraph:
    """``graph`` with ``CollectT1``, ``CollectT2`` indexed by the other robot's ``U_1`` task too:
    their projected values ``V(CollectTk, s, a~)`` are conditioned on it, not marginalized
    (Eq. 6.1's joint projected value, here over the parent's level: a lost race is then
    charged to racing)."""
    level = cooperation_levels(graph, cooperation, 2)[0]
    nodes = list(graph.nodes)
    for name in ("CollectT1", "CollectT2"):
        nodes[graph.index[name]] = CooperativeSubtask(
            nodes[graph.index[name]], level.key, level.radix
        )
    return TaskGraph(graph.root_name, nodes, graph.n_actions)


def _alpha(a: argparse.Namespace):
    """``(alpha, (high, low) for a per-entry 1/n step size or None)``."""
    kind, *ends = a.alpha.split(":")
    if kind == "lin":
        return Linear(float(ends[0]), float(ends[1]), a.steps), None
    if kind == "visits":
        return float(ends[0]), (float(ends[0]), float(ends[1]))
    return float(a.alpha), None


def _variant(a: argparse.Namespace):
    """The trash domain with ``a.algo`` changed as asked, and its multi-agent config."""
    dom = registry.get("trash")
    alpha, visits = _alpha(a)
    init_nodes = None if a.root_init is None else {"Root": a.root_init}

    def learner(graph, sets):
        made = MaxQLearner(
            graph, sets, alpha, T.GAMMA, all_states=bool(a.visited), init=T.INIT,
            init_nodes=init_nodes,
        )  # fmt: skip
        return made if visits is None else visit_step_size(made, *visits)

    levels = (("Root",), ("CollectT1", "CollectT2")) if a.two_levels else (("Root",),)
    cooperation = Cooperation(levels, wait="Wait", broadcast=a.broadcast)
    base = _team_hierarchy if a.team_root else T.trash_hierarchy
    spec = replace(
        dom.algos[a.algo],
        learner=learner,
        exploration=lambda c: EpsilonGreedy(Linear(0.5, 0.02, int(c.steps * a.eps_frac))),
        executor=ExecutorConfig(record_visited=a.visited),
    )
    if a.algo == "cooperative":
        config = replace(
            spec.multiagent, cooperation=cooperation, scheme=a.scheme, shared_tables=a.shared_tables
        )

        def graph():
            joint = T.cooperative_graph(base(), cooperation, 2)
            return collect_knows_u1(joint, cooperation) if a.collect_u1 else joint

        spec = replace(spec, make_graph=graph, multiagent=config)
    return replace(dom, algos={**dom.algos, a.algo: spec}), spec.multiagent


def main() -> None:
    a = _arguments()
    torch.set_num_threads(1)
    domain, config = _variant(a)
    start = time.perf_counter()
    seeds = list(range(a.first_seed, a.first_seed + a.seeds))
    opts = RunOptions(seeds=seeds, steps=a.steps, progress=False, tensorboard=False)
    trainer = build_trainer(domain, a.algo, opts)
    trainer.config.eval_every = 0
    trainer.train()
    gains = exact_gains(trainer, a.algo, 2, T.REFILL_PROB, config)
    mean = sum(gains) / len(gains)
    took = time.perf_counter() - start
    print(f"{[round(g, 3) for g in gains]} mean {mean:.3f} ({took:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
