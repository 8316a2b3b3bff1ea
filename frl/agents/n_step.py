"""n-step returns: transitions in, n-step transitions out, per episode.

With n steps the critic's target is ``R + gamma^k * (1 - terminated) * Q'(s_{t+k}, .)``
where ``R = r_t + gamma r_{t+1} + ... + gamma^(k-1) r_{t+k-1}`` and k = n, or fewer where
the episode ended first. The +5 of an arrival 40 steps after the decision to go reaches
that decision in 40 / n target updates instead of 40.

Holding each episode until it ends (``hold_episode``) hands out the same n-step
transitions, all at the episode's end, and where the episode terminated (a collision, an
arrival) each with its discounted cost to that end: the cost critic's target itself,
read from the episode instead of bootstrapped from Q_c (``DDPGConfig.cost_target``).
"""

from __future__ import annotations

from collections import deque
from typing import Any, NamedTuple

import numpy as np
import torch


class Transition(NamedTuple):
    obs: np.ndarray
    action: np.ndarray
    reward: float
    """The discounted reward sum over ``horizon`` steps."""
    next_obs: np.ndarray
    terminated: bool
    horizon: int
    """Steps between ``obs`` and ``next_obs``: the target bootstraps with gamma**horizon."""
    cost: float = 0.0
    """The discounted cost sum over ``horizon`` steps (collisions: a collision budget)."""
    cost_to_go: float | None = None
    """The discounted cost sum from ``obs`` to the end of an episode that terminated,
    where the accumulator holds episodes; None: not known (the episode was cut off, or
    episodes are not held)."""


class NStepAccumulator:
    """Holds the last n one-step transitions of the running episode, or with
    ``hold_episode`` all of them until it ends."""

    def __init__(self, n: int, gamma: float, hold_episode: bool = False) -> None:
        if not isinstance(n, int) or n < 1:
            raise ValueError(f"n must be a positive integer, got {n!r}")
        self.n = n
        self.gamma = gamma
        self.hold_episode = hold_episode
        self._pending: deque[Transition] = deque()

    def __len__(self) -> int:
        return len(self._pending)

    def push(
        self, obs: np.ndarray, action: np.ndarray, reward: float, next_obs: np.ndarray,
        terminated: bool, horizon: int = 1, cost: float = 0.0,
    ) -> list[Transition]:  # fmt: skip
        """Add one transition of ``horizon`` environment steps (its ``reward`` and
        ``cost`` discounted inside already); the n-step transitions now complete."""
        self._pending.append(
            Transition(obs, action, float(reward), next_obs, terminated, int(horizon), float(cost))
        )
        if terminated:
            return self._drain(terminated=True)
        if self.hold_episode or len(self._pending) < self.n:
            return []
        ready = self._combine(list(self._pending), terminated=False)
        self._pending.popleft()
        return [ready]

    def flush(self) -> list[Transition]:
        """The episode was cut off (a time limit, a new episode): every pending step
        becomes a transition that bootstraps from the last state reached."""
        return self._drain(terminated=False)

    def _drain(self, terminated: bool) -> list[Transition]:
        steps = list(self._pending)
        self._pending.clear()
        # The n-step windows push would have handed out one by one (a held episode's), then
        # the shorter last ones; only those that reach the last step end with it.
        last = len(steps)
        transitions = [
            self._combine(steps[i : i + self.n], terminated and i + self.n >= last)
            for i in range(last)
        ]
        if not (terminated and self.hold_episode):
            return transitions
        to_go = 0.0
        for i in reversed(range(last)):
            to_go = steps[i].cost + self.gamma ** steps[i].horizon * to_go
            transitions[i] = transitions[i]._replace(cost_to_go=to_go)
        return transitions

    def _combine(self, steps: list[Transition], terminated: bool) -> Transition:
        reward, cost, elapsed = 0.0, 0.0, 0
        for step in steps:
            reward += self.gamma**elapsed * step.reward
            cost += self.gamma**elapsed * step.cost
            elapsed += step.horizon
        first, last = steps[0], steps[-1]
        return Transition(first.obs, first.action, reward, last.next_obs, terminated, elapsed, cost)

    def state_dict(self) -> dict[str, Any]:
        """The pending steps as tensors (checkpoints load with ``weights_only=True``)."""
        steps = list(self._pending)
        if not steps:
            return {"count": 0}
        return {
            "count": len(steps),
            "obs": torch.from_numpy(np.stack([s.obs for s in steps]).astype(np.float32)),
            "actions": torch.from_numpy(np.stack([s.action for s in steps]).astype(np.float32)),
            "rewards": torch.tensor([s.reward for s in steps], dtype=torch.float64),
            "next_obs": torch.from_numpy(np.stack([s.next_obs for s in steps]).astype(np.float32)),
            "terminated": torch.tensor([s.terminated for s in steps]),
            "horizons": torch.tensor([s.horizon for s in steps]),
        } | self._costs(steps)

    @staticmethod
    def _costs(steps: list[Transition]) -> dict[str, torch.Tensor]:
        """Only where a step has a cost: an agent without a collision budget writes the
        checkpoint it wrote before cost critics."""
        if not any(s.cost for s in steps):
            return {}
        return {"costs": torch.tensor([s.cost for s in steps], dtype=torch.float64)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        count = int(state.get("count", 0))
        horizons = state.get("horizons")  # absent in checkpoints of one-step pushes
        costs = state.get("costs")  # absent where no pending step has a cost
        self._pending = deque(
            Transition(
                state["obs"][i].numpy(),
                state["actions"][i].numpy(),
                float(state["rewards"][i]),
                state["next_obs"][i].numpy(),
                bool(state["terminated"][i]),
                1 if horizons is None else int(horizons[i]),
                0.0 if costs is None else float(costs[i]),
            )
            for i in range(count)
        )
