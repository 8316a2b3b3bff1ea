"""A trained agent's deterministic policy filtered by its own cost critic at test time.

The actor proposes an action; where the cost critic prices it above a threshold
(discounted collisions to come), the car takes instead, of evenly spaced accelerations,
the one the reward critic values most among those priced at or below the threshold, or
the least priced where none is. This is the safety critic's action filter of Srinivasan
et al. 2020 ("Learning to be Safe: Deep RL with a Safety Critic", arXiv 2010.14603),
here on a trained driver's own critics: no teacher, no new training.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

CANDIDATES = 21
"""Evenly spaced accelerations over the action bounds that the filter may choose from
(steps of 0.1 on [-1, 1])."""


def check_threshold(threshold: Any) -> float:
    """``threshold`` as a float, or a ``ValueError`` naming it: a number >= 0."""
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)):
        raise ValueError(
            f"cost_filter must be a number >= 0 (the price allowed), got {threshold!r}"
        )
    if not math.isfinite(threshold) or threshold < 0:
        raise ValueError(f"cost_filter must be a number >= 0 (the price allowed), got {threshold}")
    return float(threshold)


class CostFilteredPolicy:
    """``observation -> action`` for ``agent`` (a :class:`frl.agents.DDPG` with a cost
    critic): its deterministic action unless its cost critic prices it above
    ``threshold``; then the best-valued of :data:`CANDIDATES` accelerations priced at or
    below it, or the least priced. ``steps`` and ``overridden`` count calls and overrides."""

    def __init__(self, agent: Any, threshold: float, candidates: int = CANDIDATES) -> None:
        self.threshold = check_threshold(threshold)
        if agent.constraint is None:
            raise ValueError(
                "cost_filter needs a model with a cost critic (trained with agent.collision_budget)"
            )
        if agent.action_dim != 1:
            raise ValueError(
                f"cost_filter chooses one acceleration; this agent has {agent.action_dim} actions"
            )
        if candidates < 2:
            raise ValueError(f"cost_filter needs at least 2 candidates, got {candidates}")
        self.agent = agent
        low, high = float(agent.scale.low[0]), float(agent.scale.high[0])
        self.grid = np.linspace(low, high, candidates, dtype=np.float32)[:, None]
        self.steps = self.overridden = 0

    def __call__(self, observation: Any) -> np.ndarray:
        action = self.agent.act(observation, explore=False)
        self.steps += 1
        actions = np.concatenate([np.reshape(action, (1, -1)), self.grid])
        flat = np.asarray(self.agent.layout.flat(observation), dtype=np.float32)
        observations = np.repeat(flat.reshape(1, -1), len(actions), axis=0)
        cost = self.agent.critic_values(observations, actions, cost=True)
        if cost[0] <= self.threshold:
            return action
        self.overridden += 1
        allowed = cost <= self.threshold
        if allowed.any():
            value = self.agent.critic_values(observations, actions)
            choice = int(np.argmax(np.where(allowed, value, -np.inf)))
        else:
            choice = int(np.argmin(cost))
        return actions[choice].reshape(np.shape(action))

    def episode_start(self) -> None:
        """The agent's own episode start, as its unfiltered test calls it."""
        self.agent.episode_start()

    @property
    def overridden_share(self) -> float:
        """The share of calls whose actor action the filter replaced."""
        return self.overridden / max(self.steps, 1)
