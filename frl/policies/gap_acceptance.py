"""A rule-based driver that reads only the grid: go when the cross traffic leaves a gap."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from frl.envs.config import EnvConfig
from frl.envs.conflicts import CrossingReader, CrossingWindow
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
        self.margin_s = margin_s
        self._crossings = CrossingReader(env, path_half_width_m, lane_half_width_m)
        self._acceleration = self._crossings.acceleration

    def __call__(self, observation: Any) -> np.ndarray:
        if isinstance(observation, Mapping):  # a Dict observation: the grid alone
            observation = observation["grid"]
        ego_speed = self._ego_speed(observation)
        stopping_distance = ego_speed * ego_speed / (2.0 * self._acceleration)
        for window in self._crossings.windows(observation):
            if self._conflicts(window, stopping_distance):
                return np.array([-1.0], dtype=np.float32)
        return np.array([1.0], dtype=np.float32)

    def _ego_speed(self, grid: np.ndarray) -> float:
        """The ego's speed (m/s), read from its own cell of the grid."""
        return self._crossings.ego_speed(grid)

    def _conflicts(self, window: CrossingWindow, stopping_distance: float) -> bool:
        if window.standing_in_path:
            return True
        car_enters = window.car_enters - self.margin_s
        car_leaves = window.car_leaves + self.margin_s
        if car_enters > window.ego_leaves or car_leaves < window.ego_enters:
            return False
        return stopping_distance < window.to_lane_m


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
        if self._crossings.committed(grid, self.distance_to_line(observation)):
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
