"""Hand-written baseline policies over the grid observation, for demos and sanity checks."""

from __future__ import annotations

import numpy as np

from frl.envs.config import GridConfig


class GapAcceptancePolicy:
    """Drive on while the cross road ahead is clear; brake while a human is close to it.

    A human counts as close when it sits in the band ``ahead_m`` metres in front of the
    ego and within ``lateral_m`` metres to either side: the cars that will cross the
    ego's path within a few seconds. No learning; a yardstick for trained agents.
    """

    def __init__(
        self,
        grid: GridConfig | None = None,
        ahead_m: tuple[float, float] = (4.0, 25.0),
        lateral_m: float = 40.0,
    ) -> None:
        grid = grid or GridConfig()
        lateral = np.linspace(*grid.lateral_range, grid.lateral_cells + 1)[:-1]
        longitudinal = np.linspace(*grid.longitudinal_range, grid.longitudinal_cells + 1)[:-1]
        rows = np.abs(lateral + (lateral[1] - lateral[0]) / 2) <= lateral_m
        cols = (longitudinal >= ahead_m[0]) & (longitudinal < ahead_m[1])
        self._watch = np.outer(rows, cols)

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        occupied = observation[..., 2] > 0
        danger = bool(np.any(occupied & self._watch))
        return np.array([-1.0 if danger else 1.0], dtype=np.float32)
