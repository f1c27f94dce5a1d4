"""Ship steering, Figures 5.7-5.12: the hierarchical hybrid against flat PGRL and actor-critic.

Each algorithm trains all seeds as one population for a fixed number of episodes per seed,
driven by ``torchrl.collectors.Collector`` with the hierarchical executor as the policy
(``hrl_torch.training.collector``). Per block of 1000 training episodes (with exploration, as the
text's curves) it records gate successes (Figure 5.7), low-level calls per episode (5.8) and steps
per episode (5.9); per block of 1000 executions, each low-level subtask's successes (5.10, 5.11).
Figure 5.12 draws the learned hybrid's greedy trajectories (root greedy, low-level subtasks
on their mean action) from the two starts given in Section 5.3.

    python scripts/fig_5_7_to_5_12_ship.py                       # hybrid, 5 seeds, 50,000 episodes
    python scripts/fig_5_7_to_5_12_ship.py --algos flat-pg actor-critic
    python scripts/fig_5_7_to_5_12_ship.py --algos hybrid-earlier  # the reading before Section
    5.3's python scripts/fig_5_7_to_5_12_ship.py --plot-only           # redraw from saved results

Writes ``<out>/<algo>.json`` (curves, wall-clock, env steps), ``<algo>.pt`` (the learner) and
the figures ``fig_5_7.png`` ... ``fig_5_12.png`` to ``--out`` (default ``runs/ship``).
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from agents.ship import DIRECTION_NODES, SUBTASK_NAMES, flat_graph, ship_hierarchy
from agents.ship_domain import DOMAIN, DOMAIN_EARLIER
from agents.ship_learners import PARAMS, make_actor_critic, make_flat_pg, make_hybrid
from agents.ship_text import (
    TEXT,
    make_actor_critic_text,
    make_flat_pg_text,
    make_hybrid_text,
)
from envs.ship import FIGURE_5_12_STARTS, ShipSteeringEnv
from hrl_torch.common.rng import BatchRNG
from hrl_torch.execution.transitions import LEVEL
from hrl_torch.modules.exploration import Greedy
from hrl_torch.training.agent import HierarchicalAgent
from hrl_torch.training.collector import collect

# the dissertation's set-up (agents/ship_text.py, TextParams) under the plain names, the
# earlier reading (ShipHyperparams) as ``-earlier``: both on the same graphs
_GRAPH = {"hybrid": ship_hierarchy, "flat-pg": flat_graph, "actor-critic": flat_graph}
_LABEL = {"hybrid": "hierarchical hybrid", "flat-pg": "flat PGRL", "actor-critic": "actor-critic"}
_MAKERS = {
    "hybrid": (make_hybrid_text, make_hybrid),
    "flat-pg": (make_flat_pg_text, make_flat_pg),
    "actor-critic": (make_actor_critic_text, make_actor_critic),
}
GRAPHS, MAKERS, LABELS = {}, {}, {}
for _name, (_text, _earlier) in _MAKERS.items():
    GRAPHS[_name] = GRAPHS[f"{_name}-earlier"] = _GRAPH[_name]
    MAKERS[_name], MAKERS[f"{_name}-earlier"] = _text, _earlier
    LABELS[_name] = f"{_LABEL[_name]} (text's set-up)"
    LABELS[f"{_name}-earlier"] = _LABEL[_name]
HYBRIDS = ("hybrid-earlier", "hybrid")


def base_params(algo: str):
    """The hyperparameters an algorithm starts from: ``PARAMS`` for the -earlier readings."""
    return PARAMS if algo.endswith("-earlier") else TEXT


def spec_of(algo: str):
    """The registered spec of ``algo`` (``ship-steering`` or ``ship-steering-earlier``)."""
    domain = DOMAIN_EARLIER if algo.endswith("-earlier") else DOMAIN
    return domain.algos[algo.removesuffix("-earlier")]


def params_of(algo: str, overrides: dict):
    """``base_params(algo)`` with the ``--set`` overrides that name its fields (typed)."""
    base = base_params(algo)
    known = {k: v for k, v in overrides.items() if hasattr(base, k)}
    typed = {}
    for key, value in known.items():
        kind = type(getattr(base, key))
        typed[key] = str(value).lower() == "true" if kind is bool else kind(value)
    return replace(base, **typed)


@dataclass
class Args:
    """Command line options."""

    algos: list[str] = field(default_factory=lambda: ["hybrid"])
    """algorithms to train (hybrid, flat-pg, actor-critic)"""
    seeds: int = 5
    """learners per algorithm (one population)"""
    episodes: int = 50_000
    """training episodes per learner"""
    envs: int | None = None
    """envs per learner (default: the algorithm's AlgoSpec)"""
    out: str = "runs/ship"
    """output folder"""
    max_minutes: float | None = None
    """stop an algorithm after this much wall-clock time"""
    plot_only: bool = False
    """only redraw the figures from saved results"""
    overrides: dict = field(default_factory=dict)
    """ShipHyperparams fields to change, e.g. pg_alpha=0.01"""


def parse() -> Args:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--algos", nargs="+", default=["hybrid"], choices=list(MAKERS))
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=50_000)
    parser.add_argument("--envs", type=int, default=None)
    parser.add_argument("--out", default="runs/ship")
    parser.add_argument("--max-minutes", type=float, default=None)
    parser.add_argument("--plot-only", action="store_true")
    parser.add_argument("--set", nargs="*", default=[], help="hyperparameters, e.g. pg_alpha=0.01")
    a = parser.parse_args()
    overrides = {}
    for item in a.set:
        key, value = item.split("=")
        if not (hasattr(PARAMS, key) or hasattr(TEXT, key)):
            parser.error(f"--set {key}: not a ShipHyperparams or TextParams field")
        overrides[key] = value
    return Args(a.algos, a.seeds, a.episodes, a.envs, a.out, a.max_minutes, a.plot_only, overrides)


def train(algo: str, args: Args, out: Path) -> dict:
    """Train one algorithm's population; save its curves and learner."""
    spec = spec_of(algo)
    params = params_of(algo, args.overrides)
    envs = args.envs or spec.envs_per_learner
    seeds = list(range(args.seeds))
    graph = GRAPHS[algo](params.out_of_bounds_reward)
    learner = MAKERS[algo](graph, len(seeds), params)
    pretrain = {}
    if hasattr(learner, "pretrain"):  # hybrid: the low level alone first (Figure 5.5)
        print(f"{algo}: low-level subtasks alone until {params.pretrain_target:.0%} success")
        pretrain = learner.pretrain(seeds)
        for name, st in pretrain.items():
            print(f"  {name}: {st['episodes']} episodes, {st['seconds']:.0f} s")
        torch.save(learner.state_dict(), out / f"{algo}-pretrained.pt")  # (ship_low_level_check)
    env = ShipSteeringEnv(seeds, envs)
    rng = BatchRNG(seeds, envs, "explore")
    exploration = spec.make_exploration(spec.train)
    agent = HierarchicalAgent(graph, learner, exploration, rng, envs, spec.executor)
    monitor = learner.monitor
    last = [0.0]

    def progress(seconds: float) -> None:
        if seconds - last[0] >= 30:
            last[0] = seconds
            done = monitor.episodes.events.min().item()
            rate = _block(monitor.episodes, "success")
            k = max(int(monitor.episodes.completed().min()) - 1, 0)
            print(
                f"  {algo}: {seconds:6.0f} s, {done:6d} episodes/seed, "
                f"gate successes in block {k}: {np.round(rate[:, k], 3).tolist()}",
                flush=True,
            )

    print(f"{algo}: {len(seeds)} seeds x {envs} envs, {args.episodes} episodes per seed")
    stats = collect(
        env,
        agent,
        until=lambda: bool((monitor.episodes.events >= args.episodes).all()),
        max_seconds=None if args.max_minutes is None else 60 * args.max_minutes,
        on_step=progress,
    )
    result = {
        "algo": algo,
        "seeds": seeds,
        "envs_per_learner": envs,
        "episodes_per_seed": monitor.episodes.events.tolist(),
        "params": asdict(params),
        "wall_seconds": stats["seconds"] + sum(st["seconds"] for st in pretrain.values()),
        "pretrain": pretrain,
        "env_steps": stats["env_steps"],
        "env_steps_per_second": stats["env_steps_per_second"],
        "curves": curves(monitor),
        "machine": {"cpus": os.cpu_count(), "torch": torch.__version__, "load": os.getloadavg()},
    }
    (out / f"{algo}.json").write_text(json.dumps(result, indent=1))
    torch.save(learner.state_dict(), out / f"{algo}.pt")
    print(
        f"{algo}: {stats['seconds']:.0f} s, {stats['env_steps']:,} env steps "
        f"({stats['env_steps_per_second']:,.0f}/s)"
    )
    return result


def _block(bins, name: str) -> np.ndarray:
    """Per-learner, per-block mean of one field (NaN for empty blocks)."""
    return bins.block_means()[name].numpy()


def curves(monitor) -> dict:
    """Per learner and block: the figure quantities."""
    ep = monitor.episodes
    count = ep.sums[0, :, : ep.n_bins].numpy()
    gates = ep.sums[1 + ep.fields.index("success"), :, : ep.n_bins].numpy()
    gate_steps = ep.sums[1 + ep.fields.index("gate_steps"), :, : ep.n_bins].numpy()
    full = count >= ep.size  # completed blocks only
    out = {
        "episodes_per_block": ep.size,
        "gate_successes": np.where(full, gates, np.nan).tolist(),
        "steps_per_episode": np.where(full, _block(ep, "steps"), np.nan).tolist(),
        "steps_to_gate": np.where(
            full & (gates > 0), gate_steps / np.maximum(gates, 1), np.nan
        ).tolist(),
        "calls_per_episode": np.where(full, _block(ep, "calls"), np.nan).tolist(),
    }
    if monitor.hierarchical:
        for name, bins in zip(SUBTASK_NAMES, monitor.low, strict=True):
            n = bins.sums[0, :, : bins.n_bins].numpy()
            ok = bins.sums[1, :, : bins.n_bins].numpy()
            out[f"low_level_successes/{name}"] = np.where(n >= bins.size, ok, np.nan).tolist()
    return out


# ---------------------------------------------------------------------- Figure 5.12
def greedy_paths(learner, graph, starts: torch.Tensor, max_steps: int = 1000):
    """Greedy paths of every learner from ``starts`` ``[n, 4]``.

    Returns positions ``[T + 1, P * n, 2]`` (frozen after the episode ends), whether each row
    passed the gate, and per row the low-level calls as ``(x, y, direction)``.
    """
    p, n = learner.n_learners, len(starts)
    env = ShipSteeringEnv(list(range(p)), n, max_episode_steps=max_steps)
    obs = env.reset_to(starts.repeat(p, 1))
    agent = HierarchicalAgent(
        graph,
        learner,
        Greedy(),
        BatchRNG(env.seeds, n, "figure"),
        n,
        DOMAIN.algos["hybrid"].executor,
        learn=False,
        evaluate=True,
        transitions=True,
    )
    direction_of = {graph.index[name]: k for k, name in enumerate(DIRECTION_NODES)}
    positions = [obs["observation"][:, :2].clone()]
    calls = [[] for _ in range(env.batch_size)]
    live = torch.ones(env.batch_size, dtype=torch.bool)
    success = torch.zeros(env.batch_size, dtype=torch.bool)
    action = agent.start(obs)
    new_call = live.clone()
    for _ in range(max_steps):
        node = graph.inst_node[agent.executor.stack.inst[:, 1].clamp_min(0)]
        for b in new_call.nonzero().flatten().tolist():
            x, y = positions[-1][b].tolist()
            calls[b].append((x, y, direction_of[int(node[b])]))
        td = env.step(action)
        positions.append(torch.where(live[:, None], td["observation"][:, :2], positions[-1]))
        success |= td["success"] & live
        live &= ~(td["terminated"] | td["truncated"])
        if not bool(live.any()):
            break
        action = agent.step(td)
        new_call = agent.batch[LEVEL]["valid"][:, 0] & live
    return torch.stack(positions), success, calls


# ---------------------------------------------------------------------- figures
def _curve(ax, values, label, scale=1.0, **kw):
    values = np.asarray(values, dtype=float) * scale
    x = (np.arange(values.shape[1]) + 1) * 1000
    keep = ~np.all(np.isnan(values), axis=0)
    if not keep.any():
        return
    mean = np.nanmean(values[:, keep], axis=0)
    ax.plot(x[keep], mean, label=f"{label} (mean of {values.shape[0]})", **kw)
    ax.fill_between(
        x[keep], np.nanmin(values[:, keep], 0), np.nanmax(values[:, keep], 0), alpha=0.2
    )


def figures(results: dict, out: Path) -> list[Path]:
    """Figures 5.7-5.11 from the saved curves (5.12 needs the learner, see ``figure_5_12``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    specs = [
        ("fig_5_7.png", "gate_successes", "successful trials per 1000 episodes", list(results)),
        ("fig_5_8.png", "calls_per_episode", "low-level subtask calls per episode", HYBRIDS),
        ("fig_5_9.png", "steps_per_episode", "primitive steps per episode", list(results)),
    ]
    specs += [
        (
            f"fig_5_{10 + k}.png",
            f"low_level_successes/{name}",
            f"{name} subtask: successes per 1000 executions",
            HYBRIDS,
        )
        for k, name in enumerate(SUBTASK_NAMES)
    ]
    paths = []
    for filename, key, ylabel, algos in specs:
        fig, ax = plt.subplots(figsize=(6.4, 4))
        for algo in algos:
            if algo in results and key in results[algo]["curves"]:
                c = results[algo]["curves"]
                blocks = min(results[algo]["episodes_per_seed"]) // c["episodes_per_block"]
                if key.startswith("low_level"):  # blocks of executions, not episodes
                    blocks = None
                _curve(ax, np.asarray(c[key], dtype=float)[:, :blocks], LABELS[algo])
                if key == "steps_per_episode":
                    _curve(
                        ax,
                        np.asarray(c["steps_to_gate"], dtype=float)[:, :blocks],
                        f"{LABELS[algo]}, successful episodes",
                        ls="--",
                    )
        if not ax.lines:
            plt.close(fig)
            continue
        ax.set_xlabel(
            "executions of the subtask" if key.startswith("low_level") else "training episodes"
        )
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / filename, dpi=110)
        plt.close(fig)
        paths.append(out / filename)
    return paths


def figure_pretrain(result: dict, out: Path) -> Path:
    """The low-level subtasks' own learning curves (the hybrid's pretraining, Figure 5.5)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4))
    for name, st in result["pretrain"].items():
        blocks = min(st["episodes"]) // 1000
        _curve(ax, np.asarray(st["success_per_block"], dtype=float)[:, :blocks], name, 1000)
    ax.set_xlabel("episodes of the subtask alone (Figure 5.5)")
    ax.set_ylabel("successes per 1000 episodes")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / "fig_low_level_pretrain.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def figure_5_12(result: dict, out: Path, algo: str = "hybrid") -> Path:
    """Greedy trajectories of the learned hybrid from the two starts of Section 5.3."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = replace(base_params(algo), **result["params"])
    graph = ship_hierarchy(params.out_of_bounds_reward)
    learner = MAKERS[algo](graph, len(result["seeds"]), params)
    learner.load_state_dict(torch.load(out / f"{algo}.pt", weights_only=True))
    positions, success, calls = greedy_paths(learner, graph, FIGURE_5_12_STARTS)
    n = len(FIGURE_5_12_STARTS)
    fig, axes = plt.subplots(1, learner.n_learners, figsize=(3.2 * learner.n_learners, 3.4))
    for p, ax in enumerate(np.atleast_1d(axes)):
        ax.plot([350, 450], [400, 400], "k-", lw=3)
        for row in range(p * n, (p + 1) * n):
            path = positions[:, row].numpy()
            ax.plot(path[:, 0], path[:, 1], lw=1)
            ax.plot(*path[0], "o", ms=9, mfc="none", mec="k")
            xs = [c[0] for c in calls[row]]
            ys = [c[1] for c in calls[row]]
            ax.plot(xs, ys, "o", ms=3, c="k")
        ok = int(success[p * n : (p + 1) * n].sum())
        ax.set(xlim=(0, 1000), ylim=(0, 1000), aspect="equal", title=f"seed {p}: {ok}/{n} gate")
        ax.tick_params(labelsize=6)
    fig.tight_layout()
    path = out / ("fig_5_12.png" if algo == "hybrid" else f"fig_5_12_{algo}.png")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _stat(values, digits=0, block=None) -> str:
    """``mean (min-max)`` over seeds of one block (``None``: each seed's last full block)."""
    v = np.asarray(values, dtype=float)
    if block is None:
        per_seed = np.array([r[~np.isnan(r)][-1] if (~np.isnan(r)).any() else np.nan for r in v])
    else:
        per_seed = v[:, block]
    lo, hi = np.nanmin(per_seed), np.nanmax(per_seed)
    return f"{np.nanmean(per_seed):.{digits}f} ({lo:.{digits}f}-{hi:.{digits}f})"


def table(results: dict) -> str:
    """Markdown rows, mean (min-max) over seeds.

    Episode quantities: the last block of 1000 episodes within the budget, the same block for
    every seed. Low-level subtasks: each seed's last completed block of 1000 executions.
    """
    rows = [
        "| algorithm | gate successes / 1000 episodes | steps per episode | steps (successful "
        "episodes) | low-level calls per episode | diagonal / straight successes per 1000 "
        "executions | episodes per seed | wall-clock (all seeds) | env steps/s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for algo, r in results.items():
        c = r["curves"]
        last = min(r["episodes_per_seed"]) // c["episodes_per_block"] - 1
        hierarchical = f"low_level_successes/{SUBTASK_NAMES[0]}" in c
        low = "-"
        if hierarchical:
            low = " / ".join(_stat(c[f"low_level_successes/{n}"]) for n in SUBTASK_NAMES)
        rows.append(
            f"| {LABELS[algo]} | {_stat(c['gate_successes'], 0, last)} | "
            f"{_stat(c['steps_per_episode'], 0, last)} | {_stat(c['steps_to_gate'], 0, last)} | "
            f"{_stat(c['calls_per_episode'], 1, last) if hierarchical else '-'} | "
            f"{low} | {min(r['episodes_per_seed']):,} | "
            f"{r['wall_seconds'] / 60:.1f} min | {r['env_steps_per_second']:,.0f} |"
        )
    return "\n".join(rows)


def bars(algo: str, r: dict) -> str:
    """One summary line: gate success, steps, calls, low-level success, wall-clock.

    The last block of 1000 episodes within the budget, mean (min-max) over seeds; steps also
    over the successful episodes alone; low-level: each seed's last block of 1000 executions.
    """
    c = r["curves"]
    last = min(r["episodes_per_seed"]) // c["episodes_per_block"] - 1
    success = np.asarray(c["gate_successes"], dtype=float) / c["episodes_per_block"]
    parts = [
        f"bars {algo}: success {_stat(success, 3, last)}",
        f"steps {_stat(c['steps_per_episode'], 0, last)}",
        f"steps (successful) {_stat(c['steps_to_gate'], 0, last)}",
    ]
    if algo in HYBRIDS:
        parts.append(f"calls {_stat(c['calls_per_episode'], 1, last)}")
        low = [np.asarray(c[f"low_level_successes/{n}"], dtype=float) / 1000 for n in SUBTASK_NAMES]
        parts.append("low-level " + " / ".join(_stat(v, 3) for v in low))
    parts.append(f"wall-clock {r['wall_seconds'] / 60:.1f} min ({len(r['seeds'])} seeds)")
    return " | ".join(parts)


def main() -> None:
    torch.set_num_threads(1)
    args = parse()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for algo in args.algos:
        if not args.plot_only:
            train(algo, args, out)
        path = out / f"{algo}.json"
        if path.exists():
            results[algo] = json.loads(path.read_text())
    for algo in MAKERS:  # draw the saved results of the other algorithms too
        path = out / f"{algo}.json"
        if algo not in results and path.exists():
            results[algo] = json.loads(path.read_text())
    paths = figures(results, out)
    for algo in HYBRIDS:
        if algo in results and (out / f"{algo}.pt").exists():
            paths.append(figure_5_12(results[algo], out, algo))
        if results.get(algo, {}).get("pretrain"):
            paths.append(figure_pretrain(results[algo], out))
    text = table(results)
    (out / "table.md").write_text(text + "\n")
    print(text)
    for algo, r in results.items():
        print(bars(algo, r))
    print("figures:", ", ".join(str(p) for p in paths))


if __name__ == "__main__":
    main()
