"""A user's code through ``--domain-module`` (graph, env factory, abstraction, spaces, rewards)
and the public API's shape and dtype mistakes: one line saying what was expected, naming the
user's file and line where the fault is in their code."""

import json
import textwrap
import warnings
from pathlib import Path

import pytest
import torch

from hrl_torch.runs import registry
from hrl_torch.runs.cli import main

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "examples" / "hrl-corridor"

HEAD = """\
from dataclasses import replace
import torch
import hrl_corridor as c
from hrl_torch.hierarchy.graph import TaskGraph
from hrl_torch.hierarchy.subtask import Subtask


def domain(name, make_graph=None, make_env=None):
    spec = c.DOMAIN.algos["q"]
    spec = replace(spec, make_graph=make_graph or spec.make_graph)
    return replace(c.DOMAIN, name=name, make_env=make_env or c.make_env, algos={"q": spec})
"""

CASES = {  # module body, the exit code, what the line says, the user's line it names
    "a graph cycle": (
        """
def graph():
    root = Subtask("Root", ["A"], n_states=1, abstract=lambda o: o["carrying"] * 0)
    a = Subtask("A", ["Root", "Left"], n_states=1, abstract=lambda o: o["carrying"] * 0)
    return TaskGraph("Root", [root, a, *c.moves()], n_actions=2)  # the user's line
DOMAIN = domain("cycle", make_graph=graph)
""",
        2,
        "cycle",
    ),
    "a missing child": (
        """
def graph():
    root = Subtask("Root", ["Nowhere", "Left"], n_states=1, abstract=lambda o: o["pos"] * 0)
    return TaskGraph("Root", [root, *c.moves()], n_actions=2)  # the user's line
DOMAIN = domain("missing", make_graph=graph)
""",
        2,
        "Nowhere",
    ),
    "duplicate names": (
        """
def graph():
    root = Subtask("Root", ["Left", "Right"], n_states=1, abstract=lambda o: o["pos"] * 0)
    return TaskGraph("Root", [root, *c.moves(), *c.moves()], n_actions=2)  # the user's line
DOMAIN = domain("duplicates", make_graph=graph)
""",
        2,
        "Left",
    ),
    "the env factory's ValueError": (
        """
def make_env(seeds, envs_per_learner, backend="torch"):
    raise ValueError("corridor length must be even")  # the user's line
DOMAIN = domain("factory", make_env=make_env)
""",
        1,
        "ValueError: corridor length must be even",
    ),
    "an abstraction of shape [B, 1]": (
        """
def graph():
    root = Subtask("Root", ["Left", "Right"], n_states=16,
                   abstract=lambda o: o["state"][:, None])  # the user's line
    return TaskGraph("Root", [root, *c.moves()], n_actions=2)
DOMAIN = domain("column", make_graph=graph)
""",
        2,
        "'Root'.abstract",
    ),
    # (a Box action space is taken since the adapter maps gymnasium's spaces as they are:
    # tests/envs/test_gymnasium_spaces.py; other action spaces are refused in one line)
    "a gymnasium env with a MultiBinary action space": (
        """
import gymnasium
from hrl_torch.env.adapters import GymnasiumBatchEnv
class Buttons(gymnasium.Env):
    observation_space = gymnasium.spaces.Discrete(4)
    action_space = gymnasium.spaces.MultiBinary(3)
def make_env(seeds, envs_per_learner, backend="torch"):
    return GymnasiumBatchEnv(Buttons, seeds, envs_per_learner)  # the user's line
DOMAIN = domain("buttons", make_env=make_env)
""",
        1,
        "GymnasiumBatchEnv takes Discrete or Box",
    ),
}


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    """Write ``body`` as a domain module; the registry restored after the test."""
    monkeypatch.setattr(registry, "_DOMAINS", dict(registry._DOMAINS))
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    monkeypatch.syspath_prepend(str(PLUGIN))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)

    def write(name: str, body: str) -> Path:
        path = tmp_path / f"{name}.py"
        path.write_text(HEAD + textwrap.dedent(body))
        return path

    return write


def _line_of(path: Path, marker: str = "# the user's line") -> int:
    (n,) = [i for i, line in enumerate(path.read_text().splitlines(), 1) if marker in line]
    return n


@pytest.mark.parametrize("case", list(CASES))
def test_a_fault_in_the_users_code_is_one_line_naming_their_line(case, user_module, capsys):
    body, code, expected = CASES[case]
    module = "user_" + "".join(ch if ch.isalnum() else "_" for ch in case)
    path = user_module(module, body)
    name = body.split('domain("')[1].split('"')[0]
    argv = ["--domain-module", module, "train", name, "--algo", "q", "--seeds", "1",
            "--steps", "64", "--no-progress", "--out", str(path.parent / "runs")]  # fmt: skip
    assert main(argv) == code
    lines = capsys.readouterr().err.strip().splitlines()
    if lines[0].endswith("rule(s) of the contract:"):  # the env check's list: a line per rule
        lines = [" ".join(lines)]
    (line,) = lines
    assert line.startswith("hrl-torch: error: ") and expected in line, line
    assert f"{path.name}:" in line, line  # the user's file (and line) named
    assert not (path.parent / "runs").exists() or not any((path.parent / "runs").iterdir())


def test_an_abstraction_out_of_range_after_step_100_names_subtask_value_and_row(
    user_module, capsys
):
    body = """
def graph():
    def abstract(o):  # in range for the first steps, then 16 + the position
        return o["state"] + 16 * (o["state"] >= 100)
    root = Subtask("Root", ["Left", "Right"], n_states=16, abstract=abstract)
    return TaskGraph("Root", [root, *c.moves()], n_actions=2)


class Drifting(c.CorridorEnv):
    def _observe(self):
        self.calls = getattr(self, "calls", 0) + 1
        out = super()._observe()
        if self.calls > 100:  # after 100 steps (beyond the 32 of the contract check)
            out["state"] = out["state"] + 100
        return out


DOMAIN = domain("drift", make_graph=graph, make_env=lambda s, e, b="torch": Drifting(s, e))
"""
    path = user_module("user_drift", body)
    argv = ["--domain-module", "user_drift", "train", "drift", "--algo", "q", "--seeds", "1",
            "--steps", "4000", "--no-progress", "--out", str(path.parent / "runs"),
            "--eval-episodes", "0"]  # fmt: skip
    assert main(argv) in (1, 2)
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "'Root'.abstract returned 1" in line and "outside [0, 16) (env row " in line, line
    assert "index" not in line.split("(at step")[0] or "out of bounds" not in line, line


def test_a_reward_of_3e38_per_step_leaves_summary_json_valid_and_says_what(user_module, capsys):
    body = """
class Huge(c.CorridorEnv):
    def _step_all(self, action):
        reward, duration, done = super()._step_all(action)
        return torch.full_like(reward, 3e38), duration, done


DOMAIN = domain("huge", make_env=lambda s, e, b="torch": Huge(s, e))
"""
    path = user_module("user_huge", body)
    out = path.parent / "runs"
    argv = ["--domain-module", "user_huge", "train", "huge", "--algo", "q", "--seeds", "2",
            "--steps", "400", "--no-progress", "--out", str(out), "--no-tensorboard"]  # fmt: skip
    with warnings.catch_warnings():  # (numpy's "invalid value" had been printed on stderr)
        warnings.simplefilter("error", RuntimeWarning)
        assert main(argv) == 0
    assert "Warning" not in capsys.readouterr().err
    (run_dir,) = out.iterdir()
    text = (run_dir / "summary.json").read_text()
    summary = json.loads(text)  # valid JSON: no Infinity, no NaN
    assert "Infinity" not in text and "NaN" not in text
    assert any("final_eval_return" in place for place in summary["not_finite"]), summary


# ---------------------------------------------------------------------- the Python API
def test_an_eval_env_of_another_population_size_is_named():
    from agents.taxi import DOMAIN
    from hrl_torch.runs.experiment import RunOptions, build_trainer

    opts = RunOptions(seeds=[0, 1], envs_per_learner=2, eval_episodes=2, tensorboard=False)
    trainer = build_trainer(DOMAIN, "maxq-q", opts)
    with pytest.raises(ValueError, match="the eval env has 3 learners .*, the training env 2"):
        type(trainer)(
            trainer.env, trainer.graph, trainer.learner, trainer.exploration, trainer.config,
            DOMAIN.make_env([0, 0, 0], 2, "torch"),
        )  # fmt: skip


def test_float_actions_are_named():
    from agents.taxi import DOMAIN

    env = DOMAIN.make_env([0], 3, "torch")
    env.reset()
    with pytest.raises(ValueError, match="integer indices into \\[0, 6\\) .*got torch.float32"):
        env.step(torch.zeros(3))


def test_a_gymnasium_dict_observation_space_is_stacked_field_by_field():
    gym = pytest.importorskip("gymnasium")
    from hrl_torch.env.adapters import GymnasiumBatchEnv

    class DictObs(gym.Env):
        observation_space = gym.spaces.Dict(
            {"pos": gym.spaces.Discrete(5), "goal": gym.spaces.Box(0, 1, (2,))}
        )
        action_space = gym.spaces.Discrete(2)

        def reset(self, seed=None, options=None):
            super().reset(seed=seed)
            return {"pos": 1, "goal": [0.5, 0.5]}, {}

        def step(self, action):
            return {"pos": int(action), "goal": [0.0, 1.0]}, 1.0, False, False, {}

    env = GymnasiumBatchEnv(DictObs, [0], 3)
    td = env.reset()
    assert td["pos"].shape == (3,) and td["goal"].shape == (3, 2)
    td = env.step(torch.ones(3, dtype=torch.long))

    class TupleObs(DictObs):
        observation_space = gym.spaces.Tuple((gym.spaces.Discrete(5), gym.spaces.Discrete(2)))

        def reset(self, seed=None, options=None):
            return (1, 0), {}

    td = GymnasiumBatchEnv(TupleObs, [0], 2).reset()  # a Tuple: fields by position
    assert td["0"].shape == (2,) and td["1"].shape == (2,)


def test_an_observation_outside_a_tabulated_graphs_states_names_value_and_row(monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGIN))
    import hrl_corridor as c
    from tensordict import TensorDict

    from hrl_torch.hierarchy.subtask import GraphError

    def observations(state):
        state = torch.as_tensor(state)
        fields = {"pos": state % c.LENGTH, "carrying": state // c.LENGTH, "state": state}
        return TensorDict(fields, batch_size=[len(state)])

    graph = c.flat_graph()
    graph.tabulate(observations(torch.arange(2 * c.LENGTH)), key="state")
    assert graph.context(observations([3, 15])).abstract.shape == (2, graph.n_nodes)
    with pytest.raises(GraphError, match="observation 'state' is 20 in env row 1, outside"):
        graph.context(observations([3, 20]))
