"""scripts/gap_reading.py: the objective difference its verdict rests on, and where it
reads each task's multiplier."""

import json

import numpy as np
import pytest
from train_helpers import load_script

gap_reading = load_script("gap_reading")


def test_priced_gap_is_the_objectives_difference_at_brake_and_at_go():
    reward_gap = np.array([-0.4, 0.1])  # Q_r(brake) - Q_r(go)
    cost_gap = np.array([-0.05, 0.02])  # Q_c(brake) - Q_c(go)
    # ((Q_r(b) - 20 Q_c(b)) - (Q_r(g) - 20 Q_c(g))) / 21
    expected = np.array([(-0.4 + 20 * 0.05) / 21, (0.1 - 20 * 0.02) / 21])
    assert gap_reading.priced_gap(reward_gap, cost_gap, 20.0) == pytest.approx(expected)
    # without a price it is the reward critic's own gap
    assert gap_reading.priced_gap(reward_gap, cost_gap, 0.0) == pytest.approx(reward_gap)


def test_multipliers_are_read_per_task_from_the_first_vehicle(tmp_path):
    budgets = {
        "client0_left": {"multiplier": 24.5},
        "client3_left": {"multiplier": 3.0},
        "client1_straight": {"multiplier": 18.25},
    }
    (tmp_path / "results.json").write_text(json.dumps({"training": {"collision_budget": budgets}}))
    assert gap_reading.multipliers(tmp_path) == {"left": 24.5, "straight": 18.25}
    (tmp_path / "results.json").write_text(json.dumps({"training": {}}))
    assert gap_reading.multipliers(tmp_path) == {}
