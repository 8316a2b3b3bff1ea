"""A rule-based driver that reads only the grid: go when the cross traffic leaves a gap."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from frl.envs.config import EnvConfig
from frl.envs.intersection import ROUTE_DISTANCE_SCALE_M


class GapAcceptancePolicy:
    """Accelerate unless a human will be in the ego's path while the ego crosses it.

    For every car in the grid moving across the ego's heading towards its path, the driver
    estimates when that car occupies the path (its lateral distance over its lateral
    speed, widened by its length and ``margin_s``). It estimates when the ego itself
    occupies that car's lane at full throttle (the car's distance ahead marks the lane;
    the ego's speed is read from its own cell). If the two windows overlap and the ego
    can still stop short of the lane, it brakes; otherwise it accelerates. Cars moving
    along the ego's heading (after a turn, or behind) are left to SUMO's car following.

    It reads nothing but the observation's grid: no position of its own, no task (even
    where the observation has the route), no SUMO. The grid cannot show where the stop
    line is, so it may brake with its nose already in the junction, waiting there for a
    far-lane car: :class:`CommittedGapAcceptancePolicy` is the same rule told the line.
    Cars beyond the grid's 80 m reach stay unseen, so some collisions remain.
    """

    def __init__(
        self,
        env: EnvConfig | None = None,
        margin_s: float = 1.0,
        path_half_width_m: float = 2.5,
        lane_half_width_m: float = 2.5,
    ) -> None:
        env = env or EnvConfig()
        grid = env.grid
        self.margin_s = margin_s
        self.path_half_width_m = path_half_width_m
        self.lane_half_width_m = lane_half_width_m
        self._acceleration = env.accel_scale
        self._vehicle_length = env.scenario.vehicle_length
        self._speed_scale = grid.speed_scale
        self._heading_scale = grid.heading_scale_deg
        lat_low, lat_high = grid.lateral_range
        lon_low, lon_high = grid.longitudinal_range
        lat_size = (lat_high - lat_low) / grid.lateral_cells
        lon_size = (lon_high - lon_low) / grid.longitudinal_cells
        self._lateral = lat_low + (np.arange(grid.lateral_cells) + 0.5) * lat_size
        self._longitudinal = lon_low + (np.arange(grid.longitudinal_cells) + 0.5) * lon_size
        self._ego_cell = (
            math.floor(-lat_low / lat_size),
            math.floor(-lon_low / lon_size),
        )

    def __call__(self, observation: Any) -> np.ndarray:
        if isinstance(observation, Mapping):  # the env's route_observation: the grid alone
            observation = observation["grid"]
        rows, cols = np.nonzero(observation[..., 2] > 0)
        ego_speed = self._ego_speed(observation)
        for row, col in zip(rows.tolist(), cols.tolist(), strict=True):
            if (row, col) == self._ego_cell:
                continue
            if self._conflicts(observation, row, col, ego_speed):
                return np.array([-1.0], dtype=np.float32)
        return np.array([1.0], dtype=np.float32)

    def _ego_speed(self, grid: np.ndarray) -> float:
        """The ego's speed (m/s), read from its own cell of the grid."""
        return float(grid[self._ego_cell][0]) * self._speed_scale

    def _conflicts(self, observation: np.ndarray, row: int, col: int, ego_speed: float) -> bool:
        lateral = float(self._lateral[row])
        ahead = float(self._longitudinal[col])
        speed = float(observation[row, col, 0]) * self._speed_scale
        heading = math.radians(float(observation[row, col, 1]) * self._heading_scale)
        lateral_speed = speed * math.sin(heading)  # + moves to the ego's right
        closing = -lateral_speed if lateral > 0 else lateral_speed
        if ahead < 0 or abs(math.cos(heading)) > 0.7:
            return False  # behind the ego, or driving along its heading
        near = abs(lateral) - self.path_half_width_m - self._vehicle_length
        if closing <= 0.1:
            # Standing, or driving away: only a car in the path now is in the way.
            return near <= 0 and abs(lateral) <= self.path_half_width_m + self._vehicle_length
        car_enters = max(0.0, near) / closing - self.margin_s
        car_leaves = (abs(lateral) + self.path_half_width_m) / closing + self.margin_s
        to_lane = ahead - self.lane_half_width_m
        past_lane = ahead + self.lane_half_width_m + self._vehicle_length
        ego_enters = self._time_to(max(0.0, to_lane), ego_speed)
        ego_leaves = self._time_to(max(0.0, past_lane), ego_speed)
        if car_enters > ego_leaves or car_leaves < ego_enters:
            return False
        stopping_distance = ego_speed * ego_speed / (2.0 * self._acceleration)
        return stopping_distance < to_lane

    def _time_to(self, distance: float, speed: float) -> float:
        """Seconds the ego needs for ``distance`` metres at full throttle from ``speed``."""
        a = self._acceleration
        return (-speed + math.sqrt(speed * speed + 2.0 * a * distance)) / a


class CommittedGapAcceptancePolicy(GapAcceptancePolicy):
    """The gap-acceptance rule that never waits inside the junction.

    Once the ego can no longer stop before the stop line (its braking distance
    v^2 / 2a reaches the distance left to the line, or it is past the line), it goes at
    full throttle: it has committed. Before that it is :class:`GapAcceptancePolicy`.
    The plain rule's collisions come after it braked with its nose past the line, where
    a car in the near lane hits it while it waits for one in the far lane
    (docs/studies.md, "Where the car stands").

    The distance to the line comes from the observation's route (the env's
    ``route_observation``), or, where the observation is the paper's grid alone, from
    ``stop_line_distance``, a callable that returns it in metres
    (:func:`frl.policies.make_yardstick` passes the env's
    :attr:`~frl.envs.IntersectionEnv.stop_line_distance_m`). It reads no other route
    information: not the task, not the destination.

    Raises:
        ValueError: when called on an observation without the route and no
            ``stop_line_distance`` was given.
    """

    def __init__(
        self,
        env: EnvConfig | None = None,
        stop_line_distance: Callable[[], float] | None = None,
        **rule: float,
    ) -> None:
        super().__init__(env, **rule)
        self._stop_line_distance = stop_line_distance

    def __call__(self, observation: Any) -> np.ndarray:
        grid = observation["grid"] if isinstance(observation, Mapping) else observation
        braking_distance = self._ego_speed(grid) ** 2 / (2.0 * self._acceleration)
        if braking_distance >= self.distance_to_line(observation):
            return np.array([1.0], dtype=np.float32)
        return super().__call__(grid)

    def distance_to_line(self, observation: Any) -> float:
        """Metres from the ego to the stop line (negative past it)."""
        if isinstance(observation, Mapping) and "route" in observation:
            return float(np.asarray(observation["route"]).reshape(-1)[3]) * ROUTE_DISTANCE_SCALE_M
        if self._stop_line_distance is None:
            raise ValueError(
                "committed_gap_acceptance reads the distance to the stop line: give it "
                "observations with the route (env.route_observation=true) or the env's "
                "stop_line_distance"
            )
        return float(self._stop_line_distance())
