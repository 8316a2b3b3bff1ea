"""The Eq. (1) grid on synthetic positions and headings (no SUMO)."""

import numpy as np
import pytest

from frl.envs.config import GridConfig
from frl.envs.observation import OccupancyGrid, relative_heading_deg
from frl.envs.sumo_backend import VehicleState

GRID = GridConfig()
ROW_WIDTH = 160.0 / 26  # metres per lateral cell
COL_LENGTH = 45.0 / 18  # metres per longitudinal cell


def cell_of(lateral: float, longitudinal: float) -> tuple[int, int]:
    """The expected cell, counted by hand: cells are [low, high) intervals."""
    row = int(np.floor((lateral + 80.0) / ROW_WIDTH + 1e-9))
    col = int(np.floor((longitudinal + 5.0) / COL_LENGTH + 1e-9))
    return row, col


def build(xy, angles, speeds, ego=0):
    vehicles = [
        VehicleState(f"v{i}", float(x), float(y), float(angle), float(speed), 0)
        for i, ((x, y), angle, speed) in enumerate(zip(xy, angles, speeds, strict=True))
    ]
    return OccupancyGrid(GRID)(vehicles, vehicles[ego])


def occupied(obs):
    return {tuple(int(i) for i in c) for c in np.argwhere(obs[..., 2] == 1.0)}


def test_car_ten_metres_ahead_of_a_north_facing_ego():
    obs = build([(0, 0), (0, 10)], [0, 0], [0, 10])
    ego_cell, ahead_cell = cell_of(0, 0), cell_of(0, 10)
    assert ego_cell == (13, 2) and ahead_cell == (13, 6)
    assert occupied(obs) == {ego_cell, ahead_cell}
    np.testing.assert_allclose(obs[ahead_cell], [10 / 20, 0, 1])
    assert obs.shape == (26, 18, 3) and obs.dtype == np.float32


def test_rotated_ego_rotates_the_grid():
    # Ego faces east (SUMO angle 90). A car 11 m east is ahead; a car 10 m south is on
    # its right; a north-bound car there has a heading of -90 relative to the ego.
    obs = build([(5, 5), (16, 5), (6, -5)], [90, 90, 0], [3, 4, 5])
    assert occupied(obs) == {cell_of(0, 0), cell_of(0, 11), cell_of(10, 1)}
    np.testing.assert_allclose(obs[cell_of(10, 1)], [5 / 20, -90 / 90, 1], atol=1e-6)
    np.testing.assert_allclose(obs[cell_of(0, 11)], [4 / 20, 0, 1], atol=1e-6)
    # The same scene seen by a north-facing ego lands in other cells.
    north = build([(5, 5), (16, 5), (6, -5)], [0, 90, 0], [3, 4, 5])
    assert occupied(north) != occupied(obs)


def test_left_is_negative_lateral():
    obs = build([(0, 0), (-30, 0)], [0, 270], [0, 0])
    assert cell_of(-30, 0) in occupied(obs)
    assert cell_of(-30, 0)[0] < 13


def test_vehicles_out_of_range_are_left_out_not_clamped():
    # 41 m ahead, 6 m behind and 81 m to the side: all outside the grid.
    obs = build([(0, 0), (0, 41), (0, -6), (81, 10)], [0, 0, 0, 0], [0, 1, 1, 1])
    assert occupied(obs) == {cell_of(0, 0)}


def test_nearest_vehicle_wins_a_shared_cell():
    obs = build([(0, 0), (1.0, 10.2), (0.5, 10.0)], [0, 0, 0], [0, 7, 3])
    assert obs[cell_of(0.5, 10.0)][0] == pytest.approx(3 / 20)


def test_relative_heading_wraps():
    assert [relative_heading_deg(a, 10.0) for a in (350.0, 10.0, 190.0, 185.0)] == [
        -20.0, 0.0, -180.0, 175.0,
    ]  # fmt: skip
