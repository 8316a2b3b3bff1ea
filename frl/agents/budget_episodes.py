"""The running training episode's collisions, which a collision budget counts when the
episode ends. Every training episode counts, exploration noise and all.

Counting only episodes driven without noise (``budget_noise_free_every``) was measured
and retired: docs/studies.md, "A budget the car can keep".
"""

from __future__ import annotations

from typing import Any


class BudgetEpisodes:
    """The running training episode's collisions and steps."""

    def __init__(self) -> None:
        self.cost, self.steps = 0.0, 0

    def step(self, cost: float) -> None:
        """Count one step of the running episode with ``cost`` collisions."""
        self.cost += cost
        self.steps += 1

    def finish(self) -> float | None:
        """The running episode ended: its collisions, or None when no step was counted
        since the last :meth:`finish`."""
        cost = self.cost if self.steps > 0 else None
        self.cost, self.steps = 0.0, 0
        return cost

    def state_dict(self) -> dict[str, Any]:
        """Plain numbers (checkpoints load with ``weights_only=True``)."""
        return {"episode_cost": self.cost, "episode_steps": self.steps}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.cost = float(state["episode_cost"])
        self.steps = int(state["episode_steps"])
