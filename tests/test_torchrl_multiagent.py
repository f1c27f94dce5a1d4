"""``MultiAgentTorchRLEnv`` on the toys of ``helpers_multiagent``."""

import pytest
import torch
from torchrl.collectors import Collector
from torchrl.envs.utils import check_env_specs

from hrl_torch.env.torchrl_multiagent import MultiAgentTorchRLEnv
from tests.helpers_multiagent import AsyncToyEnv, SyncToyEnv

TOYS = [AsyncToyEnv, SyncToyEnv]
SEEDS, E = [0, 1], 2  # B = 4 rows


@pytest.mark.parametrize("toy", TOYS)
def test_check_env_specs(toy):
    check_env_specs(MultiAgentTorchRLEnv(toy(SEEDS, E)))


@pytest.mark.parametrize("toy", TOYS)
def test_marl_keys(toy):
    env = MultiAgentTorchRLEnv(toy(SEEDS, E))
    assert env.action_keys == [("agents", "action")]
    assert env.reward_keys == [("agents", "reward")]
    assert set(env.done_keys) == {
        "done",
        "terminated",
        "truncated",
        ("agents", "done"),
        ("agents", "terminated"),
        ("agents", "truncated"),
    }
    assert env.full_action_spec["agents"].shape == (4, env.env.n_agents)
    assert env.observation_spec["agents", "acting"].dtype == torch.bool


@pytest.mark.parametrize("toy", TOYS)
def test_random_rollout_shapes_and_partial_resets(toy):
    torch.manual_seed(0)
    base = toy(SEEDS, E)
    env = MultiAgentTorchRLEnv(base)
    b, n, t = 4, base.n_agents, 40
    td = env.rollout(t, break_when_any_done=False)
    assert td.batch_size == (b, t)
    assert td["agents"].batch_size == (b, t, n)
    assert td["agents", "action"].shape == (b, t, n)
    assert td["next", "agents", "reward"].shape == (b, t, n, 1)
    assert td["next", "agents", "done"].shape == (b, t, n, 1)
    assert td["next", "done"].shape == (b, t, 1)
    assert td["next", "team_reward"].shape == (b, t)
    # per-agent flags are the row's
    done = td["next", "done"]
    assert torch.equal(td["next", "agents", "done"], done[:, :, None].expand(b, t, n, 1))
    assert done.any(), "the toys end episodes within 40 steps"
    # a finished row restarts (every agent acts); the other rows carry on
    ended = done[:, :-1, 0]
    after = td[:, 1:]
    assert after["agents", "acting"][ended].all()
    assert (after["agents", "duration"][ended] == 0).all()
    nxt = td["next"][:, :-1]
    for key in ("agents", "acting"), ("agents", "duration"):
        assert torch.equal(after[key][~ended], nxt[key][~ended])
    acting = td["agents", "acting"]
    if toy is SyncToyEnv:
        assert acting.all()
    else:
        assert not acting.all() and acting.any(-1).all()  # some, never none, decide
    # an agent that does not act gets no reward and no duration
    idle = ~td["next", "agents", "acting"]
    assert (td["next", "agents", "reward"][idle] == 0).all()
    assert (td["next", "agents", "duration"][idle] == 0).all()


@pytest.mark.parametrize("toy", TOYS)
def test_steps_match_the_batched_env(toy):
    """Until the first end, the wrapper's steps are the batched env's, key for key."""
    env = MultiAgentTorchRLEnv(toy(SEEDS, E))
    bare = toy(SEEDS, E)
    torch.manual_seed(1)
    td = env.rollout(30, break_when_any_done=True)
    bare.reset()
    for k in range(td.shape[1]):
        out = bare.step(td["agents", "action"][:, k])
        nxt = td["next"][:, k]
        assert torch.equal(nxt["agents", "reward"].squeeze(-1), out["agents", "reward"])
        assert torch.equal(nxt["agents", "acting"], out["agents", "acting"])
        assert torch.equal(nxt["team_reward"], out["reward"])
        assert torch.equal(nxt["done"].squeeze(-1), out["terminated"] | out["truncated"])
        for key in bare.agent_observation_sizes:
            assert torch.equal(nxt["agents", key], out["agents", key])
        for key in bare.observation_sizes:
            assert torch.equal(nxt[key], out[key])


def test_collector_runs():
    env = MultiAgentTorchRLEnv(AsyncToyEnv(SEEDS, E))
    collector = Collector(env, None, frames_per_batch=4 * 10, total_frames=4 * 20)
    try:
        batches = list(collector)
    finally:
        collector.shutdown()
    assert len(batches) == 2
    assert batches[0]["next", "agents", "reward"].shape[-2:] == (3, 1)


def test_rejects_other_envs():
    from tests.helpers import random_table_env

    with pytest.raises(TypeError, match="MultiAgentBatchedEnv"):
        MultiAgentTorchRLEnv(random_table_env(5, 2, seed=0))
