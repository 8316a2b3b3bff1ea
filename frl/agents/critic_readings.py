"""What an agent's critics say about given observations and actions (analysis, not
training): the mean return, or a collision budget's discounted collisions to come."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from frl.agents.sparse_linear import SparseRows


def critic_values(agent: Any, observations: Any, actions: Any, cost: bool = False) -> np.ndarray:
    """Q(s, a) of ``agent``'s online critic (a :class:`frl.agents.DDPG`) for a batch of
    observations (an array, or for a Dict space a sequence of them) and env-unit actions:
    the mean return (a quantile critic's quantiles averaged), or with ``cost`` the cost
    critic's discounted collisions to come."""
    constraint = agent.constraint
    if cost and constraint is None:
        raise ValueError("this agent has no cost critic (DDPGConfig.collision_budget)")
    if agent.layout.parts is not None and not isinstance(observations, np.ndarray):
        observations = [agent.layout.flat(o) for o in observations]
    x = torch.from_numpy(np.asarray(observations, dtype=np.float32).reshape(-1, agent.obs_dim))
    unit = agent.scale.to_unit(np.asarray(actions).reshape(len(x), -1), batch=True)
    inputs = SparseRows.from_dense(x).to(agent.device) if agent.sparse else x.to(agent.device)
    action = torch.from_numpy(unit.astype(np.float32)).to(agent.device)
    critic = agent.networks.critic
    with torch.no_grad(), agent._autocast():
        if not cost:
            q = critic(inputs, action)
        else:  # the reward critic's pass only where a cost head reads it
            head = constraint.reads_critic_hidden
            hidden = critic.values_and_hidden(inputs, action)[1] if head else None
            q = constraint.values(agent.networks.cost_critic, inputs, action, hidden)
    if q.dim() > 1:
        q = q.mean(dim=-1)
    return q.reshape(-1).double().cpu().numpy()
