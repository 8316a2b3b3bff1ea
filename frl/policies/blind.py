"""Policies that ignore what they see: the floor any learned policy must clear."""

from __future__ import annotations

import numpy as np


class ConstantPolicy:
    """Always the same acceleration, whatever the observation."""

    def __init__(self, acceleration: float) -> None:
        if not -1.0 <= acceleration <= 1.0:
            raise ValueError(f"acceleration must lie in [-1, 1], got {acceleration}")
        self._action = np.array([acceleration], dtype=np.float32)

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        return self._action.copy()


def full_throttle() -> ConstantPolicy:
    """Accelerate at +1 from the first step: a blind driver that never brakes."""
    return ConstantPolicy(1.0)


def always_brake() -> ConstantPolicy:
    """Brake at -1 every step: the ego never leaves the stop line and never collides."""
    return ConstantPolicy(-1.0)
