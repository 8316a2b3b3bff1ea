"""When the grid's crossing cars occupy the ego's path, and when the ego occupies their lanes.

Read from the Eq. (1) grid alone: each occupied cell's position, speed and relative
heading. A car that moves across the ego's heading towards its path occupies the path
from ``car_enters`` to ``car_leaves`` seconds from now (its lateral distance over its
lateral speed, widened by its length); the ego occupies that car's lane from
``ego_enters`` to ``ego_leaves`` at full throttle from its present speed (the car's
distance ahead marks the lane). The gap-acceptance rules (:mod:`frl.policies`) brake
on these windows; ``window_observation`` gives them to a learner as features
(:func:`CrossingReader.features`), so that a gap is a few numbers rather than a pattern
of cells. Nothing is read that the grid does not hold.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from frl.envs.config import EnvConfig

FEATURE_HORIZON_S = 10.0
"""The window features' times are in units of this many seconds, clipped to [0, 1]."""
SIDES = ("left", "right")
"""The sides a crossing car comes from, in the features' order (left: the near lane)."""
FEATURES_PER_SIDE = 6
WINDOW_FEATURES = FEATURES_PER_SIDE * len(SIDES)
"""Per side: a car comes, a car stands in the path, and the binding car's car_enters,
car_leaves, ego_enters, ego_leaves (see :meth:`CrossingReader.features`)."""


@dataclass(frozen=True)
class CrossingWindow:
    """One crossing car of the grid: where it comes from and the two windows (seconds)."""

    side: str
    """``left`` or ``right`` of the ego."""
    standing_in_path: bool
    """It stands (or drives away) inside the ego's path: the windows are not defined."""
    car_enters: float = 0.0
    car_leaves: float = 0.0
    ego_enters: float = 0.0
    ego_leaves: float = 0.0
    to_lane_m: float = 0.0
    """Metres from the ego's nose to the near edge of the car's lane."""


class CrossingReader:
    """The crossing cars of a grid, as :class:`CrossingWindow` s.

    Args:
        env: the grid's geometry and scales, the car length, the ego's acceleration.
        path_half_width_m: half the width of the ego's path.
        lane_half_width_m: half the width of a crossing lane.
    """

    def __init__(
        self,
        env: EnvConfig | None = None,
        path_half_width_m: float = 2.5,
        lane_half_width_m: float = 2.5,
    ) -> None:
        env = env or EnvConfig()
        grid = env.grid
        self.path_half_width_m = path_half_width_m
        self.lane_half_width_m = lane_half_width_m
        self.acceleration = env.accel_scale
        self._vehicle_length = env.scenario.vehicle_length
        self._speed_scale = grid.speed_scale
        self._heading_scale = grid.heading_scale_deg
        lat_low, lat_high = grid.lateral_range
        lon_low, lon_high = grid.longitudinal_range
        lat_size = (lat_high - lat_low) / grid.lateral_cells
        lon_size = (lon_high - lon_low) / grid.longitudinal_cells
        self._lateral = lat_low + (np.arange(grid.lateral_cells) + 0.5) * lat_size
        self._longitudinal = lon_low + (np.arange(grid.longitudinal_cells) + 0.5) * lon_size
        self.ego_cell = (
            math.floor(-lat_low / lat_size),
            math.floor(-lon_low / lon_size),
        )

    def ego_speed(self, grid: np.ndarray) -> float:
        """The ego's speed (m/s), read from its own cell of the grid."""
        return float(grid[self.ego_cell][0]) * self._speed_scale

    def committed(self, grid: np.ndarray, distance_to_line_m: float) -> bool:
        """Whether the ego can no longer stop before the stop line: its braking distance
        at full brake, from the speed in its own cell, reaches the distance left (always
        true past the line, where the distance is negative)."""
        braking_distance = self.ego_speed(grid) ** 2 / (2.0 * self.acceleration)
        return braking_distance >= distance_to_line_m

    def no_car_features(self, grid_shape: tuple[int, ...]) -> np.ndarray:
        """:meth:`features` of an empty grid of ``grid_shape``: no car coming on either side."""
        return self.features(np.zeros(grid_shape, np.float32))

    def windows(self, grid: np.ndarray) -> Iterator[CrossingWindow]:
        """The grid's crossing cars ahead of the ego, in the grid's row-major order, one at
        a time (a rule that brakes at the first conflict reads no further).

        Cars behind the ego, or driving along its heading (after a turn, or ahead in
        its lane), are left out: SUMO's car following handles them. A car that stands or
        drives away is kept only where it is inside the ego's path now."""
        ego_speed = self.ego_speed(grid)
        rows, cols = np.nonzero(grid[..., 2] > 0)
        for row, col in zip(rows.tolist(), cols.tolist(), strict=True):
            if (row, col) != self.ego_cell:
                window = self._window(grid, row, col, ego_speed)
                if window is not None:
                    yield window

    def _window(
        self, grid: np.ndarray, row: int, col: int, ego_speed: float
    ) -> CrossingWindow | None:
        lateral = float(self._lateral[row])
        ahead = float(self._longitudinal[col])
        speed = float(grid[row, col, 0]) * self._speed_scale
        heading = math.radians(float(grid[row, col, 1]) * self._heading_scale)
        lateral_speed = speed * math.sin(heading)  # + moves to the ego's right
        closing = -lateral_speed if lateral > 0 else lateral_speed
        if ahead < 0 or abs(math.cos(heading)) > 0.7:
            return None
        side = "right" if lateral > 0 else "left"
        near = abs(lateral) - self.path_half_width_m - self._vehicle_length
        if closing <= 0.1:
            in_path = near <= 0 and abs(lateral) <= self.path_half_width_m + self._vehicle_length
            return CrossingWindow(side, standing_in_path=True) if in_path else None
        to_lane = ahead - self.lane_half_width_m
        past_lane = ahead + self.lane_half_width_m + self._vehicle_length
        return CrossingWindow(
            side,
            standing_in_path=False,
            car_enters=max(0.0, near) / closing,
            car_leaves=(abs(lateral) + self.path_half_width_m) / closing,
            ego_enters=self.time_to(max(0.0, to_lane), ego_speed),
            ego_leaves=self.time_to(max(0.0, past_lane), ego_speed),
            to_lane_m=to_lane,
        )

    def time_to(self, distance: float, speed: float) -> float:
        """Seconds the ego needs for ``distance`` metres at full throttle from ``speed``."""
        a = self.acceleration
        return (-speed + math.sqrt(speed * speed + 2.0 * a * distance)) / a

    def features(self, grid: np.ndarray) -> np.ndarray:
        """``WINDOW_FEATURES`` float32 values in [0, 1], per side (left, then right):
        a car comes, a car stands in the path, and the binding car's car_enters,
        car_leaves, ego_enters and ego_leaves over :data:`FEATURE_HORIZON_S`.

        The binding car is the one whose window leaves the ego the least time: the
        smallest ``max(car_enters - ego_leaves, ego_enters - car_leaves)``, negative where
        the two overlap. Without a coming car its times read as far away (car 1, ego 0).
        """
        values = np.zeros(WINDOW_FEATURES, np.float32)
        binding: dict[str, tuple[float, CrossingWindow]] = {}
        for window in self.windows(grid):
            offset = FEATURES_PER_SIDE * SIDES.index(window.side)
            if window.standing_in_path:
                values[offset + 1] = 1.0
                continue
            slack = max(
                window.car_enters - window.ego_leaves, window.ego_enters - window.car_leaves
            )
            held = binding.get(window.side)
            if held is None or slack < held[0]:
                binding[window.side] = (slack, window)
        for index, side in enumerate(SIDES):
            offset = FEATURES_PER_SIDE * index
            held = binding.get(side)
            if held is None:
                values[offset + 2 : offset + 4] = 1.0
                continue
            window = held[1]
            times = (window.car_enters, window.car_leaves, window.ego_enters, window.ego_leaves)
            values[offset] = 1.0
            values[offset + 2 : offset + 6] = np.clip(np.array(times) / FEATURE_HORIZON_S, 0, 1)
        return values
