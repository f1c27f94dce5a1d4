"""The layers of the code (docs/design.md, "Packages"): every import of ``hrl_torch/``, ``envs/``
and ``agents/`` (top level, in functions, under TYPE_CHECKING) goes to its own layer or one below,
no cycle anywhere, no private name read across modules, no file over 600 lines."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: ``hrl_torch``'s subpackages, lowest first: each imports only its own and the ones before it
LAYERS = [
    "common",
    "hierarchy",
    "env",
    "execution",
    "modules",
    "learners",
    "analysis",
    "training",
    "multiagent",
    "runs",
]
#: what the domains may import of ``hrl_torch.runs``: specs, algorithms, registry; not the runner
AGENTS_MAY_USE = {
    "hrl_torch.runs",
    "hrl_torch.runs.algorithms",
    "hrl_torch.runs.domain",
    "hrl_torch.runs.registry",
}


def _module(root: Path, path: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources(root: Path) -> dict[str, Path]:
    return {
        _module(root, p): p
        for top in ("hrl_torch", "envs", "agents")
        for p in (root / top).rglob("*.py")
    }


def _imports(root: Path = ROOT) -> dict[str, list[tuple[str, str]]]:
    """Module -> ``(imported module, imported name)`` for every import of our own modules."""
    modules = _sources(root)
    ours = ("hrl_torch", "envs", "agents")
    out = {}
    for name, path in modules.items():
        found = []
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for alias in node.names:
                    sub = f"{node.module}.{alias.name}"
                    target = sub if sub in modules else node.module
                    if target.split(".")[0] in ours:
                        found.append((target, alias.name))
            elif isinstance(node, ast.Import):
                found += [(a.name, "") for a in node.names if a.name.split(".")[0] in ours]
        out[name] = found
    return out


def _layer(module: str) -> int:
    """The layer of a module: hrl_torch's by subpackage, then envs, then agents."""
    parts = module.split(".")
    if parts[0] == "envs":
        return len(LAYERS)
    if parts[0] == "agents":
        return len(LAYERS) + 1
    if len(parts) == 1 or parts[1] == "common":
        return 0  # the package itself holds the version and the compatibility finder
    return LAYERS.index(parts[1])


def layer_violations(imports: dict[str, list[tuple[str, str]]]) -> list[str]:
    """Every import of a module from a layer above its own, and what the domains may not use."""
    bad = []
    for m, targets in imports.items():
        for t, _ in targets:
            if t == m:
                continue
            if _layer(t) > _layer(m):
                bad.append(f"{m} imports {t} (a layer above)")
            elif (
                m.startswith("envs")
                and t.startswith("hrl_torch")
                and _layer(t) > _layer("hrl_torch.env")
            ):
                bad.append(f"{m} imports {t} (an env needs only hrl_torch.common and .env)")
            elif m.startswith("agents") and t.startswith("hrl_torch.runs"):
                if t not in AGENTS_MAY_USE:
                    bad.append(f"{m} imports {t} (domains use runs.domain, .algorithms, .registry)")
    return bad


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
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


def _graph(imports) -> dict[str, set[str]]:
    # a package's ``__init__`` importing its own submodules is no cycle; nor is ``hrl_torch``
    # (version and finder) imported from below
    return {
        m: {t for t, _ in targets if t != m and t != "hrl_torch" and not m.startswith(t + ".")}
        for m, targets in imports.items()
    }


def test_every_import_goes_to_its_own_layer_or_below():
    assert layer_violations(_imports()) == []


def test_the_layer_test_fails_on_a_planted_upward_import(tmp_path):
    for top, files in {
        "hrl_torch": {"common/ops.py": "from hrl_torch.runs.cli import main\n", "runs/cli.py": ""},
        "envs": {"grid.py": "from hrl_torch.learners.maxq import MaxQLearner\n"},
        "agents": {"taxi.py": "def f():\n    from hrl_torch.runs.experiment import run\n"},
    }.items():
        for rel, text in files.items():
            path = tmp_path / top / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
    (tmp_path / "hrl_torch" / "learners").mkdir()
    (tmp_path / "hrl_torch" / "learners" / "maxq.py").write_text("")
    (tmp_path / "hrl_torch" / "runs" / "experiment.py").write_text("")
    found = layer_violations(_imports(tmp_path))
    assert found == [
        "hrl_torch.common.ops imports hrl_torch.runs.cli (a layer above)",
        "envs.grid imports hrl_torch.learners.maxq (an env needs only hrl_torch.common and .env)",
        "agents.taxi imports hrl_torch.runs.experiment (domains use runs.domain, .algorithms, "
        ".registry)",
    ]


def test_only_the_package_file_sits_at_the_top_of_hrl_torch():
    assert sorted(p.name for p in (ROOT / "hrl_torch").glob("*.py")) == ["__init__.py"]
    assert sorted(
        p.name for p in (ROOT / "hrl_torch").iterdir() if p.is_dir() and p.name[0] != "_"
    ) == sorted([*LAYERS])


def test_no_import_cycle():
    assert _cycle(_graph(_imports())) is None


def test_no_module_imports_another_modules_private_name():
    private = [
        f"{m} imports {name} from {t}"
        for m, imports in _imports().items()
        for t, name in imports
        if name.startswith("_") and not name.startswith("__") and t != m
    ]
    assert private == []


def test_the_training_loop_imports_nothing_multi_agent():
    graph, seen, todo = _graph(_imports()), set(), ["hrl_torch.training.trainer"]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo += graph.get(m, ())
    assert not {m for m in seen if "multiagent" in m}, sorted(seen)


def test_modules_and_classes_stay_small():
    # the house rules (issue 23, issue 37): no file over 600 lines anywhere in the code, no class
    # over 20 methods, a training loop under 350 lines
    long = {
        str(p.relative_to(ROOT)): n
        for p in _sources(ROOT).values()
        if (n := len(p.read_text().splitlines())) > 600
    }
    assert long == {}
    big = {}
    for p in (ROOT / "hrl_torch").rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ClassDef):
                n = sum(isinstance(b, ast.FunctionDef | ast.AsyncFunctionDef) for b in node.body)
                if n > 20:
                    big[f"{p.relative_to(ROOT)}:{node.name}"] = n
    assert big == {}
    assert len((ROOT / "hrl_torch" / "training" / "trainer.py").read_text().splitlines()) <= 350


def test_the_design_docs_package_table_names_every_module_in_its_layer():
    rows = {}
    for line in (ROOT / "docs" / "design.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[0].isdigit():
            rows[int(cells[0])] = (cells[1].strip("`/"), {m.strip() for m in cells[3].split(",")})
    assert [rows[k][0] for k in sorted(rows)] == LAYERS, rows
    for package, listed in rows.values():
        present = {p.stem for p in (ROOT / "hrl_torch" / package).glob("*.py")} - {"__init__"}
        assert listed == present, (package, sorted(present - listed), sorted(listed - present))
