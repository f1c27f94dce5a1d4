"""GPU check of issue 27: the training step with and without CUDA-graph replay, in one run.

Measures on DEVICE (default ``cuda``), each with ``cuda_graph`` on and off:

* taxi MAXQ-Q 1 x 1: ms per batched training step;
* taxi MAXQ-Q 1000 x 1024 and the ship hybrid 1000 x 1024: env steps/s;
* taxi MAXQ-Q, 1000 seeds to the greedy threshold (mean return >= 7.5), evaluation included
  (wall seconds from the first training step to the evaluation that finds the last seed);
* whether each run's step was captured (``captured``) and, for the taxi 1 x 1 pair, whether
  graph and eager learned the same tables after the same steps (``tables_equal``).

Run from the project root with the project on ``PYTHONPATH`` (``benchmarks/gpu_check.sh``
installs the carried wheels first). ``--quick`` shrinks every size for a smoke run (also on
the CPU, where ``--device cpu`` measures the eager step only). Prints one JSON line per
measurement and writes them all to ``--out``/gpu_check.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import agents  # noqa: E402,F401  (registers the domains)
from hrl_torch.runs import registry  # noqa: E402
from hrl_torch.runs.experiment import RunOptions, build_trainer  # noqa: E402


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def _trainer(domain, algo, seeds, envs, device, graph, **kw):
    opts = RunOptions(
        seeds=list(range(seeds)),
        envs_per_learner=envs,
        progress=False,
        tensorboard=False,
        device=device,
        check_env=False,
        cuda_graph=graph,
        **kw,
    )
    return build_trainer(registry.get(domain), algo, opts)


def _captured(trainer) -> bool | None:
    from hrl_torch.training.cuda_graph import StepGraph

    step = trainer.__dict__.get("_graph")
    return step.graph is not None if isinstance(step, StepGraph) else None


def step_speed(domain, algo, seeds, envs, device, graph, seconds=3.0, warm=8) -> dict:
    """ms per batched step and env steps/s after ``warm`` steps (the capture among them)."""
    t = _trainer(domain, algo, seeds, envs, device, graph, eval_episodes=0)
    for _ in range(warm):
        t.train_step()
    _sync(device)
    n, t0 = 0, time.perf_counter()
    while True:
        for _ in range(10):
            t.train_step()
        n += 10
        _sync(device)
        if time.perf_counter() - t0 > seconds or n >= 5000:
            break
    dt = (time.perf_counter() - t0) / n
    rows = seeds * envs
    out = {"domain": domain, "algo": algo, "seeds": seeds, "envs": envs, "graph": graph}
    out |= {"ms_per_step": dt * 1e3, "env_steps_per_s": rows / dt, "steps_timed": n}
    out["captured"] = _captured(t)
    return out


def tables_equal(device, steps=60) -> dict:
    """Taxi 1 x 1 (and 2 x 4): the graph's tables against the eager step's."""
    res = {}
    for seeds, envs in ((1, 1), (2, 4)):
        tables = []
        for graph in (True, False):
            t = _trainer("taxi", "maxq-q", seeds, envs, device, graph, eval_episodes=0)
            for _ in range(steps):
                t.train_step()
            tables.append({k: v.cpu() for k, v in t.learner.state_dict().items()})
        a, b = tables
        res[f"{seeds}x{envs}"] = all(torch.equal(a[k], b[k]) for k in a if torch.is_tensor(a[k]))
    return {"tables_equal": res}


def to_threshold(seeds, envs, eval_every, device, graph, max_steps=200_000) -> dict:
    """Taxi MAXQ-Q seeds to the greedy threshold, evaluation included."""
    t = _trainer("taxi", "maxq-q", seeds, envs, device, graph)
    threshold = t.config.threshold
    hit = torch.zeros(seeds, dtype=torch.bool)
    first: list = [None] * seeds
    _sync(device)
    w0 = time.perf_counter()
    train = ev = 0.0
    nxt = eval_every
    while not bool(hit.all()) and t.step < max_steps:
        a = time.perf_counter()
        t.train_step()
        if t.step >= nxt:
            _sync(device)
            b = time.perf_counter()
            train += b - a
            mean = t.evaluate()[0].cpu()
            ev += time.perf_counter() - b
            nxt = t.step + eval_every
            for p in ((mean >= threshold) & ~hit).nonzero().flatten().tolist():
                first[p] = t.step
            hit |= mean >= threshold
        else:
            train += time.perf_counter() - a
    wall = time.perf_counter() - w0
    done = [x for x in first if x is not None]
    out = {"seeds": seeds, "envs": envs, "eval_every": eval_every, "graph": graph}
    out |= {"wall_s": wall, "train_s": train, "eval_s": ev, "reached": len(done)}
    out |= {"mean_steps_to_threshold": sum(done) / max(1, len(done)), "steps": t.step}
    out["captured"] = _captured(t)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--device", default="cuda")
    p.add_argument("--out", default=".")
    p.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    p.add_argument("--parts", default="equal,taxi1,taxi,ship,threshold")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    dev, parts = a.device, a.parts.split(",")
    big = (4, 64) if a.quick else (1000, 1024)
    thr = (8, 64, 8192) if a.quick else (1000, 512, 8192)
    modes = (True, False) if dev.startswith("cuda") else (False,)
    head = {"torch": torch.__version__, "device": dev}
    if dev.startswith("cuda"):
        head["gpu"] = torch.cuda.get_device_name(0)
    results = [head]
    print(json.dumps(head), flush=True)
    jobs = []
    if "equal" in parts and dev.startswith("cuda"):
        jobs.append(lambda: tables_equal(dev))
    for graph in modes:
        if "taxi1" in parts:
            jobs.append(lambda g=graph: step_speed("taxi", "maxq-q", 1, 1, dev, g))
        if "taxi" in parts:
            jobs.append(lambda g=graph: step_speed("taxi", "maxq-q", *big, dev, g))
        if "ship" in parts:
            jobs.append(lambda g=graph: step_speed("ship-steering-earlier", "hybrid", *big, dev, g))
        if "threshold" in parts:
            jobs.append(lambda g=graph: to_threshold(*thr, dev, g))
        if "threshold64" in parts:  # (64 envs per seed: 64,000 rows, under the graph's limit)
            jobs.append(lambda g=graph: to_threshold(thr[0], 64, 4096, dev, g))
    for job in jobs:
        try:
            r = job()
        except Exception as exc:  # (report and go on: one failure must not hide the rest)
            r = {"error": "".join(traceback.format_exception(exc)[-4:])[-1200:]}
        if dev.startswith("cuda"):
            torch.cuda.empty_cache()
        print(json.dumps(r), flush=True)
        results.append(r)
        Path(a.out).mkdir(parents=True, exist_ok=True)
        (Path(a.out) / "gpu_check.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
