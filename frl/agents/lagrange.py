"""The collision budget's Lagrange multiplier, driven by a PID rule (Stooke, Achiam and
Abbeel, "Responsive Safety in Reinforcement Learning by PID Lagrangian Methods", ICML 2020).

The agent maximises Q_r - lambda Q_c subject to a budget d on the collisions per training
episode. After every finished training episode the multiplier follows the collision rate
J of the last ``window`` episodes::

    e = J - d
    I <- max(0, I + Ki e)
    lambda = clip(Kp e + I + Kd max(0, J - J_previous), 0, LAMBDA_MAX)

lambda is in reward units per collision: a collision already costs about 14.5 of
discounted return (the -10 and the lost +5 of an arrival), so lambda = 14.5 doubles its
price. The default gains (:data:`frl.agents.config.DEFAULT_LAGRANGE_GAINS`) are sized
for that scale and for a vehicle's 1,000-1,500 training episodes at the default budget:

- Ki = 0.1: a rate 0.1 over budget (the default agent's training rate going straight
  is 0.10-0.15 late in training, with its exploration noise) raises lambda by 1 every
  100 episodes, so the price of a crash can double within the first half of training;
- Kp = 10: the same excess adds 1 at once and leaves as soon as the rate falls, which
  damps the integral's overshoot (the point of the P term in Stooke et al.);
- Kd = 0: a rate over 50 episodes moves in steps of 1/50 from one episode to the next, so
  its difference is mostly noise; damping comes from the P term.
- window = 50 episodes, about 3,000 environment steps and 375 updates at the default
  budget: long enough that one collision moves the rate by 0.02, short enough to follow
  a policy that changes over a round.
"""

from __future__ import annotations

from collections import deque
from typing import Any

LAMBDA_MAX = 100.0
"""Upper bound of the multiplier: a collision priced at about seven times what the
reward already charges. A budget the exploring car cannot meet would otherwise let the
integral grow without end (OmniSafe's ``penalty_max`` is the same 100)."""


class PIDLagrangian:
    """The multiplier of one vehicle's collision budget.

    Args:
        budget: collisions per training episode allowed, in [0, 1).
        gains: (Kp, Ki, Kd), each >= 0.
        window: episodes in the rate the rule follows.
    """

    def __init__(self, budget: float, gains: tuple[float, ...], window: int) -> None:
        if not 0 <= budget < 1:
            raise ValueError(f"budget must lie in [0, 1), got {budget!r}")
        if len(gains) != 3 or min(gains) < 0:
            raise ValueError(f"gains must be (Kp, Ki, Kd), each >= 0, got {gains!r}")
        if window < 1:
            raise ValueError(f"window must be a positive integer, got {window!r}")
        self.budget = float(budget)
        self.kp, self.ki, self.kd = (float(g) for g in gains)
        self.recent: deque[float] = deque(maxlen=int(window))
        """Collisions of the last episodes, oldest first."""
        self.integral = 0.0
        self.previous_rate = 0.0
        self.multiplier = 0.0
        """lambda, the price of a unit of Q_c in the actor's objective."""

    @property
    def collision_rate(self) -> float:
        """Mean collisions per episode over the window (0 before the first episode)."""
        return sum(self.recent) / len(self.recent) if self.recent else 0.0

    def episode_end(self, collisions: float) -> float:
        """Count a finished training episode with ``collisions`` in it; the new lambda."""
        self.recent.append(float(collisions))
        rate = self.collision_rate
        error = rate - self.budget
        self.integral = max(0.0, self.integral + self.ki * error)
        rising = max(0.0, rate - self.previous_rate)
        self.previous_rate = rate
        value = self.kp * error + self.integral + self.kd * rising
        self.multiplier = min(max(value, 0.0), LAMBDA_MAX)
        return self.multiplier

    def state_dict(self) -> dict[str, Any]:
        """Plain numbers and lists (checkpoints load with ``weights_only=True``)."""
        return {
            "recent": list(self.recent),
            "integral": self.integral,
            "previous_rate": self.previous_rate,
            "multiplier": self.multiplier,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.recent.clear()
        self.recent.extend(float(c) for c in state["recent"])
        self.integral = float(state["integral"])
        self.previous_rate = float(state["previous_rate"])
        self.multiplier = float(state["multiplier"])
