"""The import graph of ``hrl_torch`` (docs/design.md, "Module map"): no cycle, no private
name read across modules, and a training loop that knows nothing multi-agent."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "hrl_torch"


def _module(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports() -> dict[str, list[tuple[str, str]]]:
    """Module -> ``(imported module, imported name)`` for every ``hrl_torch`` import in it."""
    modules = {_module(p): p for p in PACKAGE.rglob("*.py")}
    out = {}
    for name, path in modules.items():
        found = []
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for alias in node.names:
                    sub = f"{node.module}.{alias.name}"
                    target = sub if sub in modules else node.module
                    if target.startswith("hrl_torch") and target in modules:
                        found.append((target, alias.name))
            elif isinstance(node, ast.Import):
                found += [(a.name, "") for a in node.names if a.name in modules]
        out[name] = found
    return out


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        state[node] = 2
        path.pop()
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def _graph() -> dict[str, set[str]]:
    # ``hrl_torch`` itself only re-exports the version; a submodule importing it is no cycle
    return {
        m: {t for t, _ in imports if t != m and t != "hrl_torch"}
        for m, imports in _imports().items()
    }


def test_no_import_cycle():
    assert _cycle(_graph()) is None


def test_no_module_imports_another_modules_private_name():
    private = [
        f"{m} imports {name} from {t}"
        for m, imports in _imports().items()
        for t, name in imports
        if name.startswith("_") and not name.startswith("__") and t != m
    ]
    assert private == []


def test_the_training_loop_imports_nothing_multi_agent():
    graph, seen, todo = _graph(), set(), ["hrl_torch.training.trainer"]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo += graph[m]
    assert not {m for m in seen if "multiagent" in m}, sorted(seen)


def test_modules_and_classes_stay_small():
    # the house rules (issue 23): no module over 600 lines, no class over 20 methods, a
    # training loop under 350 lines
    long = {
        str(p.relative_to(ROOT)): n
        for p in PACKAGE.rglob("*.py")
        if (n := len(p.read_text().splitlines())) > 600
    }
    assert long == {}
    big = {}
    for p in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ClassDef):
                n = sum(isinstance(b, ast.FunctionDef | ast.AsyncFunctionDef) for b in node.body)
                if n > 20:
                    big[f"{p.relative_to(ROOT)}:{node.name}"] = n
    assert big == {}
    assert len((PACKAGE / "trainer.py").read_text().splitlines()) <= 350
