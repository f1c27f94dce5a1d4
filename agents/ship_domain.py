"""The ship-steering domain and its registered configurations (Section 5.3)."""

from __future__ import annotations

from agents import ship_text
from agents.ship import (
    LOW_LEVEL_GUARD,
    flat_graph,
    ship_hierarchy,
)
from agents.ship_learners import (
    PARAMS,
    make_actor_critic,
    make_env,
    make_flat_pg,
    make_hybrid,
)
from agents.ship_neural import make_hybrid_mlp
from hrl_torch.common.config import Make
from hrl_torch.execution.executor import ExecutorConfig
from hrl_torch.modules.exploration import EpsilonGreedy, Greedy
from hrl_torch.runs.domain import AlgoSpec, DomainSpec
from hrl_torch.training.config import TrainConfig

#: about 50,000 episodes per learner at the hybrid's ~340 steps per episode
_TRAIN = TrainConfig(
    steps=17_000_000,
    eval_every=2_000_000,
    eval_episodes=100,
    eval_max_steps=1000,
    log_every=100_000,
    success_key="success",
)
_GUARDED = ExecutorConfig(max_subtask_steps=LOW_LEVEL_GUARD, on_timeout="abort")


def _text_graph(make):
    return lambda: make(ship_text.with_overrides().out_of_bounds_reward)


def _text_specs() -> dict[str, AlgoSpec]:
    """Section 5.3's set-up (``agents/ship_text.py``): the domain's own algorithms."""
    streams = 64  # agents.ship_text.STREAMS
    specs = {
        "hybrid": (ship_hierarchy, "make_hybrid_text", _GUARDED, "hybrid"),
        "flat-pg": (flat_graph, "make_flat_pg_text", ExecutorConfig(), "flat PGRL"),
        "actor-critic": (flat_graph, "make_actor_critic_text", ExecutorConfig(), "AC"),
    }
    return {
        name: AlgoSpec(
            make_graph=_text_graph(graph),
            # a plain maker: its TextParams are not swept by name
            learner=getattr(ship_text, maker),
            exploration=Make(EpsilonGreedy, epsilon=PARAMS.epsilon),
            train=_TRAIN,
            envs_per_learner=streams,
            executor=executor,
            description=f"{label} as Section 5.3 sets it (agents/ship_text.py)",
        )
        for name, (graph, maker, executor, label) in specs.items()
    }


DOMAIN = DomainSpec(
    name="ship-steering",
    description="ship steering through a gate (Miller et al. 1990), as Section 5.3 sets it",
    make_env=make_env,
    algos=_text_specs(),
)

#: the reading made before Section 5.3's set-up was reproduced (ours where the text is silent:
#: 1,024 / 512 rows, ``ShipHyperparams``), kept for comparison
DOMAIN_EARLIER = DomainSpec(
    name="ship-steering-earlier",
    description="ship steering, the earlier reading of Section 5.3 (kept for comparison)",
    make_env=make_env,
    algos={
        "hybrid": AlgoSpec(
            make_graph=lambda: ship_hierarchy(PARAMS.out_of_bounds_reward),
            learner=Make(make_hybrid, params=PARAMS),
            exploration=Make(EpsilonGreedy, epsilon=PARAMS.epsilon),
            train=_TRAIN,
            envs_per_learner=1024,
            executor=_GUARDED,
            description="hierarchical hybrid: Q(lambda) root over 8 directions, HPGRL below",
        ),
        "hybrid-mlp": AlgoSpec(
            make_graph=lambda: ship_hierarchy(PARAMS.out_of_bounds_reward),
            # (Adam over HPGRL's estimate, the heading as its sine and cosine: docs/neural-heads.md)
            learner=Make(
                make_hybrid_mlp,
                params=PARAMS,
                hidden=32,
                pg_alpha=0.001,
                adam_lr=0.001,
                wrap_heading=True,
            ),
            exploration=Make(EpsilonGreedy, epsilon=PARAMS.epsilon),
            train=_TRAIN,
            # (each row keeps LOW_LEVEL_GUARD score traces of the MLP's 193 weights)
            envs_per_learner=256,
            executor=_GUARDED,
            description="the hybrid with MLP Gaussian subtasks (scores by autograd)",
        ),
        "flat-pg": AlgoSpec(
            make_graph=lambda: flat_graph(PARAMS.out_of_bounds_reward),
            learner=Make(make_flat_pg, params=PARAMS),
            exploration=Make(Greedy),  # unused: PG nodes sample
            train=_TRAIN,
            envs_per_learner=512,
            description="flat PGRL: Gaussian over 9 tilings of 20 x 20 x 36 x 5",
        ),
        "actor-critic": AlgoSpec(
            make_graph=lambda: flat_graph(PARAMS.out_of_bounds_reward),
            learner=Make(make_actor_critic, params=PARAMS),
            exploration=Make(Greedy),  # unused: PG nodes sample
            train=_TRAIN,
            envs_per_learner=512,
            description="actor-critic (Konda): flat PGRL actor, 5-D tile-coded Q critic",
        ),
    },
)
