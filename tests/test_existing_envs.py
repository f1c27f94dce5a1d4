"""Existing envs as they are: a PettingZoo env nobody here wrote (MPE's simple_spread, the rock-
paper-scissors AEC env) through ``PettingZooBatchedEnv``, and docs/existing-envs.md's examples
(a gymnasium env with a Box action space, simple_spread) trained at their budgets."""

import importlib.util
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from hrl_torch.env.envcheck import check_env
from hrl_torch.env.pettingzoo_in import PettingZooBatchedEnv

ROOT = Path(__file__).resolve().parents[1]
needs_mpe = pytest.mark.skipif(importlib.util.find_spec("mpe2") is None, reason="no mpe2")
pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def spread(seeds, envs_per_learner, **options):
    from mpe2 import simple_spread_v3

    make = lambda: simple_spread_v3.parallel_env(N=2, max_cycles=5, **options)  # noqa: E731
    return PettingZooBatchedEnv(make, seeds, envs_per_learner)


@needs_mpe
def test_mpe_simple_spread_keeps_the_multiagent_contract():
    env = spread([0, 1], 2)
    assert (env.n_agents, env.n_actions, env.max_episode_steps) == (2, 5, 5)
    check_env(env, make_env=spread, steps=12, torchrl=True)  # a population is separate runs
    td = env.reset()
    assert td["agents", "observation"].shape == (4, 2, 12)
    for _ in range(5):
        td = env.step(torch.ones(4, 2, dtype=torch.long))
    assert td["truncated"].all() and not td["terminated"].any()  # the env's own time limit
    own = td["agents", "reward"]
    assert torch.equal(td["reward"], own.sum(1)) and bool((own < 0).all())
    td = env.step(torch.zeros(4, 2, dtype=torch.long))
    assert td["is_init"].all() and (td["reward"] == 0).all()  # next-step auto-reset
    with pytest.raises(ValueError, match="same Discrete action space, got Box"):
        spread([0], 1, continuous_actions=True)


def test_an_aec_env_comes_in_through_aec_to_parallel():
    rps = pytest.importorskip("pettingzoo.classic.rps_v2", reason="rps needs pygame")
    make = lambda seeds, e: PettingZooBatchedEnv(lambda: rps.env(max_cycles=3), seeds, e)  # noqa: E731
    env = make([0], 3)
    assert env.agent_observation_sizes == {"observation": 4} and env.n_actions == 3
    check_env(env, make_env=make, steps=10)
    env.reset()
    td = env.step(torch.tensor([[0, 1]] * 3))  # rock against paper
    assert td["agents", "reward"].tolist() == [[-1.0, 1.0]] * 3
    assert td["agents", "observation"].tolist() == [[1, 0]] * 3  # each sees the other's move


def page_blocks(page: str) -> str:
    text = (ROOT / page).read_text()
    code = re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)
    return "\n".join(code).replace("TrainConfig(", "TrainConfig(progress=False, ")


@pytest.mark.slow
@needs_mpe
def test_the_docs_gymnasium_box_and_pettingzoo_examples_learn(monkeypatch, tmp_path):
    from hrl_torch.common.stats import iqm

    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__docs__"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exec(compile(page_blocks("docs/existing-envs.md"), "existing-envs.md", "exec"), namespace)
    reach = namespace["reach"].final_eval
    assert all(v > -8.0 for v in reach), reach  # shortest paths average -5; random walks -30s
    untrained = namespace["untrained"].tolist()
    trained = np.array(namespace["spread"].final_eval)
    assert max(untrained) < -33.0 and iqm(trained) > -26.0, (untrained, trained)
    box = namespace["Reach"]().action_space
    assert box.shape == (2,) and type(box).__name__ == "Box"
