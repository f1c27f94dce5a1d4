"""0.1's user code runs on 0.2 unchanged, with a DeprecationWarning naming each replacement.

The files in ``tests/compat/`` are 0.1's as users had them: the README's training script and the
multi-agent walkthrough of f3a1bd5 (with ``Trainer(multiagent=)``), and a domain file with a
positional 0.1 ``AlgoSpec``. Each runs in its own interpreter, so every old module warns afresh.
"""

import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from hrl_torch.common import compat

ROOT = Path(__file__).resolve().parents[1]
COMPAT = ROOT / "tests" / "compat"

#: every ``hrl_torch`` import line of the README's and docs' examples at f3a1bd5
OLD_IMPORTS = """
from hrl_torch.analysis import FiniteModel, check_abstractions
from hrl_torch.devices import constant_on
from hrl_torch.env import BatchedEnv
from hrl_torch.envcheck import check_env
from hrl_torch.exploration import EpsilonGreedy, Linear, Greedy
from hrl_torch.graph import Primitive, Subtask, TaskGraph
from hrl_torch.learners import HPGRLLearner, PGConfig, MaxQLearner
from hrl_torch.multiagent import Cooperation, MultiAgentConfig, cooperative_graph
from hrl_torch.multiagent_env import MultiAgentBatchedEnv
from hrl_torch.multiagent_factory import MultiAgentFactory
from hrl_torch.pettingzoo_env import MultiAgentAECEnv, MultiAgentParallelEnv
from hrl_torch.sweep import parse_grid, run_sweep
from hrl_torch.trainer import Trainer, TrainConfig
from hrl_torch import registry
"""

_RUN = """
import runpy, sys, warnings
warnings.simplefilter("always", DeprecationWarning)
torch_seen = []
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always", DeprecationWarning)
    {body}
for w in caught:
    if issubclass(w.category, DeprecationWarning) and "0.3.0" in str(w.message):
        print("DEPRECATED", str(w.message).replace(chr(10), " "), "@", w.filename)
"""


def _run(body: str, cwd: Path, timeout: int = 240, env_extra: dict | None = None) -> list[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(COMPAT)])}
    env.update(env_extra or {})
    code = _RUN.format(body=body.replace("\n", "\n    "))
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return [line for line in out.stdout.splitlines() if line.startswith("DEPRECATED")]


def test_every_old_import_of_the_docs_resolves_and_names_its_new_path(tmp_path):
    found = _run(f"exec({OLD_IMPORTS!r}, {{}})", tmp_path)
    olds = {
        line.split()[1]
        for line in OLD_IMPORTS.strip().splitlines()
        if line.split()[1] not in ("hrl_torch", "hrl_torch.analysis", "hrl_torch.learners")
    }
    for old in olds:
        name = old.removeprefix("hrl_torch.")
        new = "hrl_torch." + compat.MOVED[name]
        assert any(f" {old}" in m and new in m for m in found), (old, found)
    assert any("hrl_torch.registry moved to hrl_torch.runs.registry" in m for m in found)
    # the warning points at the user's line, not at importlib or the finder
    assert all("compat.py" not in m and "importlib" not in m for m in found), found


def test_an_old_path_is_the_same_module_object():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import hrl_torch.trainer as old
    import hrl_torch.training.trainer as new

    assert old is new


def test_an_unknown_name_on_an_old_package_path_is_still_an_attribute_error():
    import hrl_torch.env

    with pytest.raises(AttributeError):
        hrl_torch.env.NoSuchThing  # noqa: B018


def test_the_0_1_readme_training_script_runs(tmp_path):
    script = (COMPAT / "readme_0_1.py").read_text()
    for old, new in {
        "envs_per_learner=256": "envs_per_learner=4",
        "steps=60_000": "steps=400",
        "eval_every=5_000": "eval_every=0",
        "envs_per_learner=100": "envs_per_learner=2",
        "seeds = list(range(10))": "seeds = list(range(2))",
        "TrainConfig(": "TrainConfig(progress=False, eval_max_steps=50, ",
    }.items():
        assert old in script
        script = script.replace(old, new)
    found = _run(f"exec({script!r}, {{'__name__': '__main__'}})", tmp_path)
    assert any("hrl_torch.trainer moved to hrl_torch.training.trainer" in m for m in found)
    assert (tmp_path / "taxi.pt").is_file()


def test_the_0_1_multiagent_script_with_trainer_multiagent_runs(tmp_path):
    script = (COMPAT / "multiagent_0_1.py").read_text()
    for old, new in {
        "seeds, steps = [0, 1, 2], 12_000": "seeds, steps = [0, 1], 300",
        "eval_episodes=50": "eval_episodes=2",
        "num_cycles=100": "num_cycles=5",
        "TrainConfig(": "TrainConfig(progress=False, eval_max_steps=40, ",
    }.items():
        assert old in script
        script = script.replace(old, new)
    found = _run(f"exec({script!r}, {{'__name__': '__main__'}})", tmp_path)
    trainer = [m for m in found if "Trainer(multiagent=config) is 0.1's" in m]
    assert len(trainer) == 1, found


def test_the_0_1_domain_file_with_a_positional_algo_spec_trains_from_the_cli(tmp_path):
    body = (
        "sys.argv = ['hrl-torch', '--domain-module', 'corridor_0_1', 'train', 'corridor-0-1',"
        " '--algo', 'q', '--seeds', '1', '--steps', '300', '--out', 'runs', '--eval-episodes',"
        " '2']\n"
        "from hrl_torch.runs import cli\n"
        "try:\n"
        "    cli.main()\n"
        "except SystemExit as e:\n"
        "    assert not e.code, e.code"
    )
    found = _run(body, tmp_path)
    spec = [m for m in found if "AlgoSpec(make_graph, make_learner" in m]
    assert len(spec) == 2, found  # one per AlgoSpec call of the file (maxq-q and q)
    assert any("corridor_0_1.py" in m for m in spec), spec
    assert list((tmp_path / "runs").glob("corridor-0-1__q__*/summary.json"))


def test_a_schedule_on_its_0_2_0_path_warns_and_is_the_same_class():
    from hrl_torch.modules import schedules

    with pytest.warns(DeprecationWarning, match=r"exploration\.Linear moved to .*schedules"):
        from hrl_torch.modules.exploration import Linear
    assert Linear is schedules.Linear
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # today's names: no warning
        from hrl_torch.modules.exploration import EpsilonGreedy  # noqa: F401
        from hrl_torch.modules.schedules import VisitCount  # noqa: F401
