"""``check_any_device`` on a new small domain: the documented two-rooms example and three ways
a user's own env or subtask breaks the any-device rules (docs/your-own-hierarchy.md).

Each break must be found without a GPU, named by the file and line that made it.
"""

import types
from pathlib import Path

import pytest
import torch

import agents  # noqa: F401  (registers the domains)
from hrl_torch.learners import MaxQLearner
from hrl_torch.modules.exploration import EpsilonGreedy
from hrl_torch.runs import registry
from hrl_torch.runs.cli import main
from hrl_torch.runs.devicecheck import DeviceRuleError, check_any_device
from hrl_torch.runs.experiment import RunOptions, build_trainer
from hrl_torch.training.config import TrainConfig
from hrl_torch.training.trainer import Trainer
from scripts.example_two_rooms import COLS, MOVES, ROWS, GoTo, TwoRoomsEnv, two_rooms_hierarchy

PLUGIN = Path(__file__).resolve().parents[1] / "examples" / "hrl-corridor"


def _line(marker: str) -> str:
    """``tests/test_devicecheck.py:N`` of the line holding ``marker`` (below)."""
    lines = Path(__file__).read_text().splitlines()
    n = next(i for i, text in enumerate(lines, 1) if marker in text and "_line(" not in text)
    return f"tests/test_devicecheck.py:{n}"


class CopiesItsTable(TwoRoomsEnv):
    """Moves its module-level table to the device at every step."""

    def _step_all(self, action):
        moves = MOVES.to(action.device)  # BREAK-COPY
        row = (self.row + moves[action, 0]).clamp(0, ROWS - 1)
        col = (self.col + moves[action, 1]).clamp(0, COLS - 1)
        self.row, self.col = row, col
        at_goal = self.row * COLS + self.col == ROWS * COLS - 1
        reward = torch.where(at_goal, 10.0, -1.0)
        return reward, torch.ones_like(reward), at_goal


class ReadsBack(TwoRoomsEnv):
    """Branches in Python on a tensor value."""

    def _step_all(self, action):
        reward, duration, at_goal = super()._step_all(action)
        if bool(at_goal.any()):  # BREAK-READ
            reward = reward + 0.0
        return reward, duration, at_goal


class RewardOnTheHost(TwoRoomsEnv):
    """Makes its reward on the CPU, whatever its device."""

    def _step_all(self, action):  # REWARD-HOST
        reward, duration, at_goal = super()._step_all(action)
        return torch.full((self.batch_size,), -1.0), duration, at_goal


def initiable_on_the_host(subtask, obs):
    """A subtask's initiation set made on the CPU, whatever the run's device."""
    return torch.ones(obs["cell"].shape[0], dtype=torch.bool)


def _builder(env_cls=TwoRoomsEnv, initiable=None, eval_env_cls=TwoRoomsEnv):
    def build(device: str):
        graph = two_rooms_hierarchy()
        for node in graph.nodes:
            if isinstance(node, GoTo) and initiable is not None:
                node.initiable = types.MethodType(initiable, node)
        learner = MaxQLearner(graph, 2, alpha=0.5, gamma=1.0).to(device)
        env = env_cls([0, 1], envs_per_learner=2).to(device)
        eval_env = eval_env_cls([7, 7], envs_per_learner=3).to(device)
        config = TrainConfig(steps=10, eval_every=0, progress=False)
        exploration = EpsilonGreedy(0.1)
        return Trainer(env, graph.to(device), learner, exploration, config, eval_env)

    return build


def test_the_documented_example_keeps_every_rule():
    report = check_any_device(_builder())
    assert report.ok, report.findings
    report.raise_if_any()


def test_a_table_moved_to_the_device_in_the_step_is_found_where_it_is_moved():
    report = check_any_device(_builder(CopiesItsTable))
    assert len(report.findings) == 1, report.findings
    (finding,) = report.findings
    assert finding.startswith(_line("BREAK-COPY")) and "to_device" in finding
    assert "constant_on" in finding  # (what to do instead)


def test_a_python_branch_on_a_tensor_is_found_on_the_cpu_and_on_meta():
    report = check_any_device(_builder(ReadsBack))
    at = _line("BREAK-READ")
    assert [f.split(": ")[0] for f in report.findings] == [at, at], report.findings
    assert "[item, 70 in 70 steps on the CPU]" in report.findings[0]
    assert "training step on 'meta'" in report.findings[1]
    with pytest.raises(DeviceRuleError, match="breaks the any-device rules: 2 finding"):
        report.raise_if_any()


def test_an_evaluation_env_that_reads_every_step_is_found():
    """Only the eval env reads (a domain's own ``make_eval_env``): the evaluation pass finds it,
    where every step of the evaluation reads, not every ``READ_EVERY``."""
    report = check_any_device(_builder(eval_env_cls=ReadsBack))
    assert len(report.findings) == 1, report.findings
    assert report.findings[0].startswith(_line("BREAK-READ"))
    assert "steps of a greedy evaluation]" in report.findings[0]


def test_a_subtask_that_answers_on_the_cpu_is_named_on_meta():
    report = check_any_device(_builder(initiable=initiable_on_the_host))
    assert len(report.findings) == 1, report.findings
    at = _line("def initiable_on_the_host")  # (where the subtask's code is, not the framework's)
    said = f"'ToDoor'.initiable ({at}) returned a tensor on cpu, the run is on meta"
    assert said in report.findings[0] and "training step on 'meta'" in report.findings[0]


def test_an_env_that_answers_on_the_cpu_is_named_on_meta():
    report = check_any_device(_builder(RewardOnTheHost))
    assert len(report.findings) == 1, report.findings
    at = _line("REWARD-HOST")
    said = f"RewardOnTheHost._step_all ({at}) returned 'reward' on cpu, the env is on meta"
    assert said in report.findings[0], report.findings


def test_a_device_named_with_an_index_is_the_device_without_one():
    """``cpu:0`` (as ``cuda:0``): the run's tensors report ``cpu``; nothing may call that a
    different device (the ship's graph is not tabulated: every subtask answers each step)."""
    opts = RunOptions(seeds=[0], envs_per_learner=2, eval_episodes=2, device="cpu:0")
    opts.progress = opts.tensorboard = False
    trainer = build_trainer(registry.get("ship-steering-earlier"), "hybrid", opts)
    for _ in range(5):
        trainer.train_step()
    assert trainer.evaluate()[0].shape == (1,)


def test_a_registered_configuration_keeps_every_rule():
    def build(device):
        opts = RunOptions(seeds=[0, 1], envs_per_learner=2, eval_episodes=0, device=device)
        opts.progress = opts.tensorboard = opts.check_env = False
        return build_trainer(registry.get("small-agv"), "har", opts)

    assert check_any_device(build, steps=20).findings == []


LEAKY = """
import dataclasses

import torch
from hrl_corridor import DOMAIN, CorridorEnv

BONUS = torch.tensor([0.0, 0.5])


class LeakyCorridor(CorridorEnv):
    def _step_all(self, action):
        reward, duration, delivered = super()._step_all(action)
        return reward + BONUS.to(action.device)[self.carrying], duration, delivered


def make_env(seeds, envs_per_learner, backend="torch"):
    return LeakyCorridor(seeds, envs_per_learner)


DOMAIN = dataclasses.replace(DOMAIN, name="leaky-corridor", make_env=make_env)
"""


@pytest.mark.slow  # (10 s: the named lines of the documented example are checked fast above)
def test_hrl_torch_check_names_the_line_of_a_plugin_s_env(tmp_path, capsys, monkeypatch):
    """``hrl-torch --domain-module M check NAME``: the walkthrough's corridor passes; a copy
    whose env moves a module-level table at every step fails, naming that line."""
    (tmp_path / "leaky_corridor.py").write_text(LEAKY)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.syspath_prepend(str(PLUGIN))
    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    modules = ["--domain-module", "hrl_corridor", "--domain-module", "leaky_corridor"]
    assert main([*modules, "check", "corridor"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "corridor --algo maxq-q: ok",
        "corridor --algo q: ok",
    ]
    assert main([*modules, "check", "leaky-corridor", "--algo", "q"]) == 1
    out = capsys.readouterr().out.splitlines()
    line = 1 + LEAKY.splitlines().index(next(t for t in LEAKY.splitlines() if "BONUS.to" in t))
    assert out[0] == "leaky-corridor --algo q: 1 finding(s)"
    assert out[1].startswith(f"  - {tmp_path.name}/leaky_corridor.py:{line}: a copy of host")
