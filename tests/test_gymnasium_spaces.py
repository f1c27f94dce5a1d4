"""Existing gymnasium envs in as they are (``hrl_torch.env.adapters.GymnasiumBatchEnv``):
``Box`` actions of any shape, ``Dict`` / ``MultiDiscrete`` / ``Tuple`` observations, the
``decode`` hook, each through the env contract check (issue 35)."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces

from hrl_torch.env.adapters import GymnasiumBatchEnv, stack_observations
from hrl_torch.env.envcheck import check_env


class ArmEnv(gym.Env):
    """A plain gymnasium env (no hrl_torch base class): a 2-joint arm on a 5 x 5 grid of cells.

    Observation ``Dict(cell=MultiDiscrete([5, 5]), angles=Box(2), parts=Tuple(Discrete(3),
    Box(1)))``, action ``Box(-1, 1, (2,))`` (joint velocities); 20 steps an episode.
    """

    def __init__(self):
        self.observation_space = spaces.Dict(
            {
                "cell": spaces.MultiDiscrete([5, 5]),
                "angles": spaces.Box(-np.pi, np.pi, (2,), np.float32),
                "parts": spaces.Tuple((spaces.Discrete(3), spaces.Box(0, 1, (1,), np.float32))),
            }
        )
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.angles = np.zeros(2, np.float32)
        self.t = 0

    def _obs(self):
        cell = np.clip(((self.angles + np.pi) / (2 * np.pi) * 5).astype(np.int64), 0, 4)
        part = np.array([abs(self.angles[0]) / np.pi], np.float32)
        return {"cell": cell, "angles": self.angles.copy(), "parts": (int(cell[0]) % 3, part)}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.angles = self.np_random.uniform(-1, 1, 2).astype(np.float32)
        self.t = 0
        return self._obs(), {}

    def step(self, action):
        assert action.shape == (2,) and action.dtype == np.float32
        self.angles = np.clip(self.angles + 0.3 * action, -np.pi, np.pi).astype(np.float32)
        self.t += 1
        reward = -float(np.abs(self.angles).sum())
        return self._obs(), reward, False, self.t >= 20, {}


def _cell_state(obs: dict) -> dict:
    """The abstraction hook: a MultiDiscrete cell as one integer state, the rest kept."""
    return {"cell": obs["cell"][:, 0] * 5 + obs["cell"][:, 1], "angles": obs["angles"]}


def test_a_dict_observation_and_box_action_env_keeps_the_contract():
    env = GymnasiumBatchEnv(ArmEnv, seeds=[0, 1], envs_per_learner=3)
    assert env.n_actions is None and env.action_bounds == ([-1.0, -1.0], [1.0, 1.0])
    td = env.reset()
    assert td["cell"].shape == (6, 2) and td["cell"].dtype == torch.int64
    assert td["angles"].shape == (6, 2) and td["angles"].dtype == torch.float32
    assert td["parts", "0"].shape == (6,) and td["parts", "1"].shape == (6, 1)
    check_env(env, steps=30)
    td = env.step(torch.full((6, 2), 0.5))
    assert torch.all(td["duration"] == 1) and td["reward"].shape == (6,)


def test_decode_is_the_abstraction_hook():
    env = GymnasiumBatchEnv(ArmEnv, seeds=[0], envs_per_learner=4, decode=_cell_state)
    td = env.reset()
    assert set(td.keys()) >= {"cell", "angles"} and "parts" not in td.keys()
    assert td["cell"].shape == (4,) and int(td["cell"].max()) < 25
    check_env(env, steps=25)


def test_gymnasium_s_own_box_action_env_keeps_the_contract():
    env = GymnasiumBatchEnv(lambda: gym.make("Pendulum-v1"), seeds=[0, 1], envs_per_learner=2)
    assert env.action_bounds == ([-2.0], [2.0])
    check_env(env, steps=20)
    env.reset()
    with pytest.raises(
        ValueError, match=r"outside Box\(-2.0, 2.0, \(1,\), float32\) \(env row 3\)"
    ):
        env.step(torch.tensor([[0.0], [1.0], [-1.5], [9.0]]))


def test_a_multidiscrete_observation_stacks_and_an_unsupported_action_space_is_one_line():
    space = spaces.MultiDiscrete([3, 4])
    stacked = stack_observations([np.array([1, 2]), np.array([0, 3])], space)
    assert torch.equal(stacked, torch.tensor([[1, 2], [0, 3]]))

    class MultiAction(ArmEnv):
        def __init__(self):
            super().__init__()
            self.action_space = spaces.MultiDiscrete([2, 2])

    with pytest.raises(ValueError, match=r"GymnasiumBatchEnv takes Discrete or Box$"):
        GymnasiumBatchEnv(MultiAction, seeds=[0], envs_per_learner=1)
