"""frl/envs/conflicts.py: the windows in which the grid's crossing cars occupy the ego's
path, and the ego their lanes, that the gap-acceptance rules brake on."""

import numpy as np
import pytest

from frl.envs import EnvConfig
from frl.envs.config import RETIRED_ENV_OPTIONS
from frl.envs.conflicts import CrossingReader
from frl.retirement import RetiredOptionError

EGO = (13, 2)  # the default grid's ego cell


def grid_with(*cars: tuple[int, int, float, float], ego_speed: float = 0.0) -> np.ndarray:
    """A default grid with the ego and ``(row, column, speed channel, heading channel)`` cars."""
    grid = np.zeros((26, 18, 3), np.float32)
    grid[EGO] = [ego_speed, 0.0, 1.0]
    for row, column, speed, heading in cars:
        grid[row, column] = [speed, heading, 1.0]
    return grid


def test_a_coming_car_gives_its_window_and_the_egos_hand_computed():
    # Row 20 lies 46.15 m to the right, column 8 16.25 m ahead (cells of 6.15 m x 2.5 m).
    # Speed channel 0.5 (10 m/s), heading -1 (-90 degrees): it drives straight at the
    # ego's path. It enters the path (2.5 m half-width, 5 m long) after
    # (46.15 - 7.5) / 10 s and leaves it after (46.15 + 2.5) / 10 s; the ego from rest
    # at 1 m/s^2 reaches its lane (2.5 m half-width) after sqrt(2 * 13.75) s and is past
    # it (and its own 5 m) after sqrt(2 * 23.75) s.
    lateral = -80.0 + 20.5 * 160.0 / 26.0
    [window] = CrossingReader(EnvConfig()).windows(grid_with((20, 8, 0.5, -1.0)))
    assert (window.side, window.standing_in_path) == ("right", False)
    assert window.car_enters == pytest.approx((lateral - 7.5) / 10.0)
    assert window.car_leaves == pytest.approx((lateral + 2.5) / 10.0)
    assert window.ego_enters == pytest.approx(np.sqrt(2 * 13.75))
    assert window.ego_leaves == pytest.approx(np.sqrt(2 * 23.75))
    assert window.to_lane_m == pytest.approx(13.75)
    [moving] = CrossingReader(EnvConfig()).windows(grid_with((20, 8, 0.5, -1.0), ego_speed=0.25))
    assert moving.ego_enters == pytest.approx(-5.0 + np.sqrt(25.0 + 2 * 13.75))  # from 5 m/s


def test_cars_behind_along_the_heading_or_driving_away_are_left_out_a_car_in_the_path_is_not():
    reader = CrossingReader(EnvConfig())
    ignored = [
        (20, 0, 0.5, -1.0),  # behind the ego
        (20, 8, 0.5, 0.0),  # driving along the ego's heading
        (20, 8, 0.5, 1.0),  # driving away to the right
        (20, 8, 0.0, 1.0),  # standing, far from the path
    ]
    for car in ignored:
        assert list(reader.windows(grid_with(car))) == [], car
    [standing] = reader.windows(grid_with((12, 6, 0.0, 1.0)))  # 3 m to the left, stopped
    assert (standing.side, standing.standing_in_path) == ("left", True)


def test_the_window_observation_is_retired_and_loads_only_off():
    assert RETIRED_ENV_OPTIONS["window_observation"].off is False
    saved = {**EnvConfig().to_dict(), "window_observation": False}
    assert EnvConfig.from_dict(saved) == EnvConfig()
    with pytest.raises(RetiredOptionError, match=r"^env\.window_observation=True was retired: "):
        EnvConfig.from_dict({**saved, "window_observation": True})
