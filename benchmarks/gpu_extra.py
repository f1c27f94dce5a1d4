"""The rest of issue 27's GPU check, beside ``gpu_check.py`` (same run, same JSON lines).

Parts (``--parts``, comma-separated):

* ``smoke``: every registered domain x algorithm on DEVICE (2 seeds x 4 envs): 8 training
  steps (the CUDA graph captured after the warm-up) and one evaluation; OK, whether the step
  was captured (and why not), or the error with its innermost frames.
* ``syncs``: host synchronisations per eager training step, counted by
  ``torch.cuda.set_sync_debug_mode("warn")``, for the four configurations the issue names.
* ``kernels``: CUDA kernels per training step (``torch.profiler``), eager and replayed.
* ``sizes``: ms per step and env steps/s at 1 x 1, 10 x 512, 100 x 2048 and 1000 x 1024 for
  taxi MAXQ-Q, small-AGV HAR and the ship hybrid, graph on and off.
* ``ship``: the ship hybrid replayed against eager with static and with compacted rings
  (``pg_traces.STATIC_RING_ENTRIES``).
* ``breakdown``: the CUDA kernels and aten ops that take a taxi step's time at 1000 x 1024.
* ``evaluation``: one greedy evaluation (taxi MAXQ-Q, 1000 seeds x 100 episodes; small-AGV
  HAR, 100 seeds x 4), reading every step with immediate checks (the CPU's way) against
  deferred checks read every ``evaluation.READ_EVERY`` steps; the same numbers, seconds each.

Run from the project root with the project on ``PYTHONPATH``; writes ``--out``/gpu_extra.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import traceback
import warnings
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from gpu_check import _captured, _sync, _trainer, step_speed  # noqa: E402

import agents  # noqa: E402,F401  (registers the domains)
from hrl_torch.runs import registry  # noqa: E402

NAMED = [("taxi", "maxq-q"), ("small-agv", "har"), ("ship-steering-earlier", "hybrid")]
NAMED.append(("four-agv-earlier", "cooperative"))
SIZES = [(1, 1), (10, 512), (100, 2048), (1000, 1024)]


def _error(exc: BaseException) -> str:
    frames = traceback.format_exception(exc)
    return "".join(frames[-4:])[-1200:]


def _short_evaluation(trainer, steps: int = 64) -> None:
    """A continuing evaluation of at most ``steps`` steps (the smoke checks that it runs)."""
    ev = trainer.evaluator
    if dataclasses.is_dataclass(ev) and {"horizon", "max_steps"} <= set(vars(ev)):
        trainer.evaluator = dataclasses.replace(ev, horizon=steps, max_steps=steps)


def smoke(device: str, pairs=None) -> list[dict]:
    """Every registered domain x algorithm: 8 steps and one evaluation on ``device``."""
    if not pairs:  # (round-robin over the domains: a cut-off run still covers each)
        algos = {n: list(registry.get(n).algos) for n in registry.names()}
        rounds = range(max(map(len, algos.values())))
        pairs = [(n, a[i]) for i in rounds for n, a in algos.items() if i < len(a)]
    out = []
    for domain, algo in pairs:
        t0 = time.perf_counter()
        r = {"part": "smoke", "domain": domain, "algo": algo}
        try:
            t = _trainer(domain, algo, 2, 4, device, True, eval_episodes=2)
            _short_evaluation(t)
            for _ in range(8):
                t.train_step()
            t.evaluate()
            _sync(device)
            step = t.__dict__.get("_graph")
            r |= {"ok": True, "captured": _captured(t)}
            r["refused"] = getattr(step, "failed", None)
        except Exception as exc:  # (report each and go on)
            r |= {"ok": False, "error": _error(exc)}
        r["s"] = round(time.perf_counter() - t0, 2)
        print(json.dumps(r), flush=True)
        out.append(r)
    return out


def syncs(device: str, steps: int = 20) -> list[dict]:
    """Host syncs per eager training step (CUDA's sync debug mode), seeds 4 x envs 64."""
    out = []
    if not device.startswith("cuda"):
        return out
    for domain, algo in NAMED:
        r = {"part": "syncs", "domain": domain, "algo": algo}
        try:
            t = _trainer(domain, algo, 4, 64, device, False, eval_episodes=0)
            for _ in range(70):  # (past the first block of random draws)
                t.train_step()
            _sync(device)
            torch.cuda.set_sync_debug_mode("warn")
            with warnings.catch_warnings(record=True) as seen:
                warnings.simplefilter("always")
                for _ in range(steps):
                    t.train_step()
            torch.cuda.set_sync_debug_mode(0)
            where = [str(w.message)[:120] for w in seen][:5]
            r |= {"syncs_per_step": len(seen) / steps, "first": where}
        except Exception as exc:
            torch.cuda.set_sync_debug_mode(0)
            r["error"] = _error(exc)
        print(json.dumps(r), flush=True)
        out.append(r)
    return out


def kernels(device: str, steps: int = 10) -> list[dict]:
    """CUDA kernels and graph launches per training step, eager and replayed."""
    from torch.profiler import ProfilerActivity, profile

    out = []
    for (domain, algo), graph in [(p, g) for p in NAMED[:3] for g in (False, True)]:
        r = {"part": "kernels", "domain": domain, "algo": algo, "graph": graph}
        try:
            t = _trainer(domain, algo, 10, 512, device, graph, eval_episodes=0)
            for _ in range(8):
                t.train_step()
            _sync(device)
            acts = [ProfilerActivity.CPU, ProfilerActivity.CUDA]
            with profile(activities=acts) as prof:
                for _ in range(steps):
                    t.train_step()
                _sync(device)
            events = prof.events()
            gpu = [e for e in events if e.device_type == torch.autograd.DeviceType.CUDA]
            launches = [e for e in events if e.name == "cudaGraphLaunch"]
            r |= {"kernels_per_step": len(gpu) / steps, "graph_launches": len(launches)}
            r["captured"] = _captured(t)
        except Exception as exc:
            r["error"] = _error(exc)
        print(json.dumps(r), flush=True)
        out.append(r)
    return out


def sizes(device: str, seconds: float, pairs=None, shapes=None) -> list[dict]:
    """ms per step and env steps/s over the issue's sizes, graph on and off."""
    out = []
    for domain, algo in pairs or NAMED[:3]:
        for seeds, envs in shapes or SIZES:
            for graph in (True, False):
                try:
                    r = step_speed(domain, algo, seeds, envs, device, graph, seconds=seconds)
                except Exception as exc:
                    r = {"domain": domain, "algo": algo, "seeds": seeds, "envs": envs}
                    r |= {"graph": graph, "error": _error(exc)}
                r["part"] = "sizes"
                torch.cuda.empty_cache()
                print(json.dumps(r), flush=True)
                out.append(r)
    return out


def ship(device: str, seconds: float) -> list[dict]:
    """The ship hybrid: replayed (static rings) against eager, static and compacted rings."""
    from hrl_torch.learners import pg_traces

    out = []
    default = pg_traces.STATIC_RING_ENTRIES
    runs = [(s, e, True, default) for s, e in SIZES[:2]]
    runs += [(s, e, False, default) for s, e in SIZES]
    runs += [(s, e, False, limit) for s, e in SIZES[:2] for limit in (0, 1 << 62)]
    for seeds, envs, graph, limit in runs:
        pg_traces.STATIC_RING_ENTRIES = limit
        try:
            r = step_speed(
                "ship-steering-earlier", "hybrid", seeds, envs, device, graph, seconds=seconds
            )
        except Exception as exc:
            r = {"seeds": seeds, "envs": envs, "graph": graph, "error": _error(exc)}
        finally:
            pg_traces.STATIC_RING_ENTRIES = default
        r |= {"part": "ship", "static_ring_entries": limit}
        torch.cuda.empty_cache()
        print(json.dumps(r), flush=True)
        out.append(r)
    return out


def breakdown(device: str, steps: int = 5) -> list[dict]:
    """The CUDA kernels that take the time of a taxi MAXQ-Q step at 1000 x 1024 (eager)."""
    from torch.profiler import ProfilerActivity, profile

    t = _trainer("taxi", "maxq-q", 1000, 1024, device, False, eval_episodes=0)
    for _ in range(5):
        t.train_step()
    _sync(device)
    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        for _ in range(steps):
            t.train_step()
        _sync(device)
    rows = []
    for e in prof.key_averages():
        cuda_us = getattr(e, "device_time_total", 0) or getattr(e, "cuda_time_total", 0)
        if e.device_type == torch.autograd.DeviceType.CUDA and cuda_us:
            rows.append((cuda_us / steps / 1e3, e.count / steps, e.key[:90]))
    rows.sort(reverse=True)
    ops = []
    for e in prof.key_averages():
        cuda_us = getattr(e, "device_time_total", 0) or getattr(e, "cuda_time_total", 0)
        if e.key.startswith("aten::") and cuda_us:
            ops.append((cuda_us / steps / 1e3, e.count / steps, e.key))
    ops.sort(reverse=True)
    r = {"part": "breakdown", "kernels_ms_per_step": rows[:15], "aten_ms_per_step": ops[:15]}
    r["kernel_ms_total"] = sum(x[0] for x in rows)
    print(json.dumps(r), flush=True)
    return [r]


def evaluation(device: str) -> list[dict]:
    """One evaluation, the CPU's way (a read every step) against the off-CPU way, in turn."""
    from hrl_torch.common import devices

    out = []
    for domain, algo, seeds, episodes in (
        ("taxi", "maxq-q", 1000, 100),
        ("small-agv", "har", 100, 4),
    ):
        t = _trainer(domain, algo, seeds, 8, device, False, eval_episodes=episodes)
        for _ in range(40):
            t.train_step()
        _short_evaluation(t, 2000)
        found = {}
        for way, static in (("every step", False), ("deferred", None), ("every step", False)):
            devices.STATIC_SHAPES = static
            try:
                _sync(device)
                start = time.perf_counter()
                mean = t.evaluate()[0].tolist()
                seconds = time.perf_counter() - start
            finally:
                devices.STATIC_SHAPES = None
            same = found.setdefault("mean", mean) == mean
            r = {"part": "evaluation", "domain": domain, "algo": algo, "seeds": seeds}
            r |= {"episodes": episodes, "way": way, "seconds": seconds, "same": same}
            print(json.dumps(r), flush=True)
            out.append(r)
        torch.cuda.empty_cache()
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--device", default="cuda")
    p.add_argument("--out", default=".")
    p.add_argument("--parts", default="syncs,kernels,sizes,smoke")
    p.add_argument("--seconds", type=float, default=1.5, help="timing per size")
    p.add_argument("--pairs", default="", help="smoke/sizes: only these DOMAIN/ALGO,...")
    p.add_argument("--shapes", default="", help="sizes: only these SEEDSxENVS,...")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    pairs = [tuple(x.split("/")) for x in a.pairs.split(",") if x] or None
    results: list = [{"torch": torch.__version__, "device": a.device}]
    Path(a.out).mkdir(parents=True, exist_ok=True)
    for part in a.parts.split(","):
        if part == "smoke":
            results += smoke(a.device, pairs)
        elif part == "syncs":
            results += syncs(a.device)
        elif part == "kernels":
            results += kernels(a.device)
        elif part == "sizes":
            shapes = [tuple(map(int, x.split("x"))) for x in a.shapes.split(",") if x]
            results += sizes(a.device, a.seconds, pairs, shapes or None)
        elif part == "ship":
            results += ship(a.device, a.seconds)
        elif part == "breakdown":
            results += breakdown(a.device)
        elif part == "evaluation":
            results += evaluation(a.device)
        else:
            raise SystemExit(f"unknown part {part!r}")
        (Path(a.out) / "gpu_extra.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
