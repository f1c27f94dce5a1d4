"""A user's own domain without editing the repository: an installed plugin package (entry-point
group ``hrl_torch.domains``) and ``--domain-module``, both trained from the CLI."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import agents  # noqa: F401  (the built-in domains, registered before the tests copy the registry)
from hrl_torch.runs import registry
from hrl_torch.runs.cli import main

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "examples" / "hrl-corridor"


def hrl_torch(*args, pythonpath: str, cwd) -> subprocess.CompletedProcess:
    """The command in its own process, so the installed plugin's entry points are fresh."""
    env = {**os.environ, "PYTHONPATH": pythonpath}
    cmd = [sys.executable, "-m", "hrl_torch.runs.cli", "--project", str(ROOT), *args]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """``pip install`` of the example plugin (a copy, so the repository gets no build files)."""
    tmp = tmp_path_factory.mktemp("plugin")
    shutil.copytree(PLUGIN, tmp / "src")
    site = tmp / "site"
    pip = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation"]
    subprocess.run([*pip, "--target", str(site), str(tmp / "src")], check=True, timeout=300)
    return site


@pytest.mark.slow  # (16 s; --domain-module plugins train from the CLI fast in test_algorithms)
def test_an_installed_plugin_is_listed_and_trains_from_the_cli(installed, tmp_path):
    listed = hrl_torch("list", pythonpath=str(installed), cwd=tmp_path)
    assert listed.returncode == 0, listed.stderr
    assert "corridor [plugin hrl-corridor]: fetch at the left end" in listed.stdout
    assert "taxi [built-in]: " in listed.stdout  # the built-in domains stay
    out = tmp_path / "runs"
    run = hrl_torch(
        "train", "corridor", "--algo", "maxq-q", "--seeds", "3", "--out", str(out),
        "--no-progress", pythonpath=str(installed), cwd=tmp_path,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    (run_dir,) = out.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    # learned: every seed reaches the optimal greedy return (about -0.5) within 3,000 steps
    assert all(r["steps_to_threshold"] is not None for r in summary["per_seed"]), summary
    assert (run_dir / "checkpoint.pt").exists()
    # and the checkpoint alone resumes it (the plugin is found again by name)
    again = hrl_torch(
        "train", "--resume", str(run_dir / "checkpoint.pt"), "--steps", "3200", "--no-progress",
        pythonpath=str(installed), cwd=tmp_path,
    )  # fmt: skip
    assert again.returncode == 0, again.stderr


def test_domain_module_registers_a_module_s_domain(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGIN))
    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    assert main(["--domain-module", "hrl_corridor", "list"]) == 0
    # with the example also pip-installed (docs §5 shows both routes) it stays the plugin's
    out = capsys.readouterr().out
    assert "corridor [module hrl_corridor]: " in out or "corridor [plugin hrl-corridor]: " in out
    args = ["--domain-module", "hrl_corridor", "train", "corridor", "--algo", "q", "--seeds", "2"]
    assert main([*args, "--steps", "400", "--out", str(tmp_path), "--no-progress"]) == 0


def test_an_installed_plugin_s_module_named_again_is_the_same_domain(monkeypatch):
    """Docs §5 in order: pip-install the example, then ``--domain-module hrl_corridor``."""
    monkeypatch.syspath_prepend(str(PLUGIN))
    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    registry.register("corridor", "hrl_corridor:DOMAIN", source="plugin hrl-corridor")
    registry.load_module("hrl_corridor")
    assert registry.source("corridor") == "plugin hrl-corridor"
    assert registry.get("corridor").name == "corridor"


def test_bad_domain_modules_and_clashes_are_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    assert main(["--domain-module", "no_such_module", "list"]) == 2
    assert capsys.readouterr().err.strip() == "hrl-torch: error: No module named 'no_such_module'"
    assert main(["--domain-module", "json", "list"]) == 2
    assert capsys.readouterr().err.strip() == (
        "hrl-torch: error: module 'json' defines no DOMAIN or DOMAINS (DomainSpec) and registers "
        "no algorithm"
    )
    (tmp_path / "clash.py").write_text(
        "from dataclasses import replace\n"
        "from agents.taxi import DOMAIN as TAXI\n"
        "DOMAIN = replace(TAXI)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["--domain-module", "clash", "list"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "hrl-torch: error: domain 'taxi' is registered twice: agents.taxi:DOMAIN (built-in) and "
        "DomainSpec 'taxi' (module clash); rename one"
    )


def test_a_broken_plugin_entry_is_a_clear_error(monkeypatch, capsys):
    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    registry.register("broken", "no_such_pkg:DOMAIN", source="plugin broken-pkg")
    with pytest.raises(ValueError, match=r"domain 'broken' \(plugin broken-pkg\): cannot load"):
        registry.get("broken")
    assert main(["train", "broken", "--algo", "x"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hrl-torch: error: domain 'broken' (plugin broken-pkg): cannot load ")


TWO_ROBOTS = ROOT / "examples" / "hrl-two-robots"


@pytest.mark.slow  # (9 s: the walkthrough's code runs fast in test_docs_blocks)
def test_the_multi_agent_walkthrough_domain_trains_from_the_cli(tmp_path, monkeypatch, capsys):
    """docs/multiagent-walkthrough.md's plugin: an episodic two-agent domain, CLI end to end."""
    monkeypatch.syspath_prepend(str(TWO_ROBOTS))
    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    out = tmp_path / "runs"
    for algo in ("cooperative", "selfish"):
        args = ["--domain-module", "hrl_two_robots", "train", "two-robots", "--algo", algo]
        assert main([*args, "--seeds", "3", "--out", str(out), "--no-progress"]) == 0
    for run_dir in out.iterdir():
        summary = json.loads((run_dir / "summary.json").read_text())
        # an untrained team walks into the 30-step limit (return -30); learned: about -5
        finals = [r["final_eval_return"] for r in summary["per_seed"]]
        assert all(f >= -6.5 for f in finals), (run_dir.name, finals)
        episodes = (run_dir / "eval_episodes.csv").read_text()
        assert "agents.pos=" in episodes and "boxes=" in episodes
        assert (run_dir / "checkpoint.pt").exists()


def test_a_module_that_raises_while_importing_is_one_line(tmp_path, capsys, monkeypatch):
    (tmp_path / "broken_domains.py").write_text("raise RuntimeError('boom\\nsecond line')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    assert main(["--domain-module", "broken_domains", "list"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "hrl-torch: error: module 'broken_domains' failed to import: RuntimeError: boom"
    ]
    # installed as a plugin, it is one line of the list and hides no other domain
    registry.register("broken", "broken_domains:DOMAIN", source="plugin broken")
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "broken [plugin broken]: domain 'broken' (plugin broken): cannot load" in out
    assert "taxi [built-in]: " in out
