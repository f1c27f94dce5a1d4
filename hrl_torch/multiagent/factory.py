"""Building multi-agent agents for the ``Trainer`` (its ``AgentFactory`` for Chapter 6 envs)."""

from __future__ import annotations

from dataclasses import dataclass, field

from hrl_torch.multiagent.cooperative import MultiAgentAgent, MultiAgentConfig, agent_rng
from hrl_torch.training.metrics import ratio


@dataclass
class MultiAgentFactory:
    """``MultiAgentAgent``s over the rows of a multi-agent env of ``n_agents`` agents.

    Attributes:
        n_agents: agents per env row.
        config: how the agents cooperate (``hrl_torch.multiagent.cooperative.MultiAgentConfig``).
    """

    n_agents: int
    config: MultiAgentConfig = field(default_factory=MultiAgentConfig)

    def __call__(self, graph, learner, exploration, env, stream, executor_config, **options):
        """An agent over ``env``'s rows (``hrl_torch.training.agent.AgentFactory``)."""
        e, config = env.envs_per_learner, self.config
        rng = agent_rng(env.seeds, e, self.n_agents, stream).to(env.device)
        return MultiAgentAgent(
            graph,
            learner,
            exploration,
            rng,
            e,
            self.n_agents,
            executor_config,
            cooperation=config.cooperation,
            scheme=config.scheme,
            shared_tables=config.shared_tables,
            communication=config.communication,
            **options,
        )

    def table_sets(self, n_learners: int) -> int:
        """A table set per seed and agent (or per seed with shared tables)."""
        return self.config.table_sets(n_learners, self.n_agents)

    def training_metrics(self, graph, calls) -> dict[str, list[float]]:
        """COM-Cooperative HRL: the share of ``U_l`` choices made communicating."""
        com = self.config.communication
        if com is None:
            return {}
        asked = calls[:, graph.index[com.com]]
        not_asked = calls[:, graph.index[com.not_com]]
        return {"charts/communication_rate": ratio(asked, asked + not_asked)}
