"""Which training episodes a collision budget counts, and the running one's collisions.

The multiplier (:mod:`frl.agents.lagrange`) follows a collision rate. Counted over every
training episode, that is the exploring car's rate: the exploration noise alone makes
some crossings unsafe, so a budget below that floor is out of reach whatever the policy
learns, and the multiplier becomes a penalty that grows with time (docs/studies.md,
"A budget the car can keep"). With ``noise_free_every = k`` every k-th training episode
after the warm-up is driven by the policy without noise, the policy that is tested, and
only those episodes count. They train the agent like any other episode.

The schedule is a count, not a draw, so it takes nothing from the run's random streams
and a checkpoint restores it exactly.
"""

from __future__ import annotations

from typing import Any


class BudgetEpisodes:
    """The episodes a collision budget counts (all, or every ``noise_free_every``-th after
    the warm-up, driven without noise), and the running one's collisions and steps."""

    def __init__(self, noise_free_every: int) -> None:
        # DDPGConfig.budget_noise_free_every has checked it (an integer >= 0).
        self.noise_free_every = noise_free_every
        self.policy_episodes = 0
        """Training episodes begun after the warm-up (what the schedule counts)."""
        self.noise_free = False
        """Whether the running episode is driven without exploration noise."""
        self.cost, self.steps = 0.0, 0
        """The running episode's collisions and steps."""

    def begin(self, in_warmup: bool) -> None:
        """A training episode begins; ``in_warmup``: its first action is a warm-up one."""
        every = self.noise_free_every
        self.noise_free = (
            bool(every) and not in_warmup and self.policy_episodes % every == every - 1
        )
        if not in_warmup:
            self.policy_episodes += 1

    def step(self, cost: float) -> None:
        """Count one step of the running episode with ``cost`` collisions."""
        self.cost += cost
        self.steps += 1

    def finish(self) -> float | None:
        """The running episode ended: its collisions if the budget counts it, else None
        (also when no step was counted since the last :meth:`finish`)."""
        counted = self.steps > 0 and (self.noise_free_every == 0 or self.noise_free)
        cost = self.cost
        self.cost, self.steps = 0.0, 0
        return cost if counted else None

    def state_dict(self) -> dict[str, Any]:
        """Plain numbers (checkpoints load with ``weights_only=True``)."""
        return {
            "episode_cost": self.cost,
            "episode_steps": self.steps,
            "policy_episodes": self.policy_episodes,
            "noise_free": self.noise_free,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`; a checkpoint written before the schedule existed
        counted every episode and has only the running episode's numbers."""
        self.cost = float(state["episode_cost"])
        self.steps = int(state["episode_steps"])
        self.policy_episodes = int(state.get("policy_episodes", 0))
        self.noise_free = bool(state.get("noise_free", False))
