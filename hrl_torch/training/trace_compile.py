"""A recorded training step compiled by inductor (``StepGraph(backend="inductor")``; the CPU).

``StepGraph``'s trace backend records a step's aten ops with the tensors they read. Here
that list becomes one ``torch.fx`` graph: every tensor the step read but did not make (its
state, cached index tables) is a graph input, every op a node on its recorded arguments, an
op's output the node later ops read. ``torch._inductor.compile_fx`` then compiles it like
any captured graph (functionalised: in-place writes to the inputs are written back), so a
replay is one call into generated C++ loops with no dispatch per op and no Python. The
inputs are the recorded tensors themselves, passed on every call: the replay reads and
writes the same storage, as a CUDA graph does; no guard is checked (``StepGraph`` keeps
them in place). Measured in benchmarks/RESULTS.md ("The recorded step compiled").
"""

from __future__ import annotations

import operator
from collections.abc import Callable

import torch
from torch import fx


def trace_module(ops: list) -> tuple[fx.GraphModule, list[torch.Tensor]]:
    """The graph of recorded ``(func, args, kwargs, out)`` ops and the tensors it reads."""
    graph, node_of, inputs = fx.Graph(), {}, []

    def arg(x):
        if isinstance(x, torch.Tensor):
            node = node_of.get(id(x))
            if node is None:  # read, not made by the step: an input
                node = node_of[id(x)] = graph.placeholder(f"in{len(inputs)}")
                inputs.append(x)
            return node
        if isinstance(x, (list, tuple)):
            return type(x)(arg(v) for v in x)
        return x

    for func, args, kwargs, out in ops:
        node = graph.call_function(func, arg(args), {k: arg(v) for k, v in kwargs.items()})
        if isinstance(out, (list, tuple)):
            for i, o in enumerate(out):
                if isinstance(o, torch.Tensor):
                    node_of[id(o)] = graph.call_function(operator.getitem, (node, i))
        elif isinstance(out, torch.Tensor):  # (an in-place op: its input's node from here on)
            node_of[id(out)] = node
    graph.output(None)
    return fx.GraphModule(torch.nn.Module(), graph), inputs


def compile_trace(ops: list) -> Callable[[], None]:
    """The recorded step as one inductor-compiled call (raises what the compiler raises)."""
    from torch._inductor.compile_fx import compile_fx

    module, inputs = trace_module(ops)
    with torch.no_grad():
        compiled = compile_fx(module, inputs)

    def replay() -> None:
        with torch.no_grad():
            compiled(*inputs)

    return replay
