"""Where each vehicle's collision budget stands at the end of training
(frl.federation.collision_budget), against hand-computed numbers."""

import dataclasses

import numpy as np
import pytest

from frl.episodes import EpisodeRecord
from frl.federation.collision_budget import budget_end_state, budget_lines, round_record


def episodes(collisions: int, total: int) -> list[EpisodeRecord]:
    return [
        EpisodeRecord(
            "left", -10.0 if i < collisions else 6.0, i < collisions, i >= collisions, False, 50
        )
        for i in range(total)
    ]


def test_a_round_counts_its_episodes_and_keeps_the_last_multiplier():
    multipliers = np.array([np.nan, 1.0, np.nan, 2.5, np.nan], np.float32)
    rates = np.array([np.nan, 0.1, np.nan, 0.08, np.nan], np.float32)
    assert round_record(episodes(3, 40), multipliers, rates) == {
        "episodes": 40,
        "collisions": 3,
        "teacher_episodes": 0,
        "teacher_collisions": 0,
        "multiplier": 2.5,
        "followed_rate": pytest.approx(0.08),
    }
    assert round_record(episodes(0, 5), np.full(5, np.nan))["multiplier"] is None
    assert round_record([], None) == {
        "episodes": 0,
        "collisions": 0,
        "teacher_episodes": 0,
        "teacher_collisions": 0,
        "multiplier": None,
        "followed_rate": None,
    }


def test_the_episodes_a_teacher_drove_are_not_the_budgets():
    own = episodes(2, 10)
    teachers = [dataclasses.replace(e, teacher_drove=True) for e in episodes(4, 6)]
    record = round_record(own + teachers, None)
    assert (record["episodes"], record["collisions"]) == (10, 2)
    assert (record["teacher_episodes"], record["teacher_collisions"]) == (6, 4)
    end = budget_end_state([record], 0.02)
    assert end["last_round_collision_rate"] == pytest.approx(0.2)
    (line,) = budget_lines({"client0_left": end})
    assert "20.0% over its last round (its own episodes; its teacher drove 6 more)" in line


def test_a_kept_budget_with_a_settled_multiplier():
    rounds = [
        {"episodes": 200, "collisions": 20, "multiplier": 4.0},
        {"episodes": 250, "collisions": 6, "multiplier": 6.0},
        {"episodes": 300, "collisions": 9, "multiplier": 6.4},
    ]
    end = budget_end_state(rounds, 0.02)
    assert end["last_round_collision_rate"] == pytest.approx(0.03)  # 1.5 times the budget
    assert end["kept"] is True
    assert end["multiplier_change_last_round"] == pytest.approx(0.4)
    assert end["levelled_off"] is True  # 0.4 <= max(0.64, 0.5)
    assert end["collision_rate_per_round"] == pytest.approx([0.1, 0.024, 0.03])


def test_a_budget_out_of_reach_and_a_multiplier_that_keeps_rising():
    rounds = [
        {"episodes": 200, "collisions": 30, "multiplier": 8.0},
        {"episodes": 200, "collisions": 38, "multiplier": 19.9},
        {"episodes": 200, "collisions": 38, "multiplier": 24.8},
    ]
    end = budget_end_state(rounds, 0.02)
    assert end["kept"] is False and end["levelled_off"] is False  # 19% against 2%; +4.9
    (line,) = budget_lines({"client0_left": end})
    assert line.startswith("client0_left: training collisions 19.0% over its last round")
    assert (
        "NOT kept" in line and "multiplier 24.80 (+4.90 over the last round: still moving)" in line
    )


def test_one_round_cannot_say_whether_the_multiplier_settled():
    end = budget_end_state([{"episodes": 10, "collisions": 0, "multiplier": 0.0}], 0.05)
    assert end["kept"] is True and end["levelled_off"] is None
    assert (
        budget_end_state([{"episodes": 0, "collisions": 0, "multiplier": None}], 0.05)["kept"]
        is None
    )


def test_the_end_state_gives_the_rate_the_multiplier_followed():
    rounds = [{"episodes": 200, "collisions": 24, "multiplier": 3.2, "followed_rate": 0.1}]
    assert budget_end_state(rounds, 0.02)["followed_collision_rate"] == 0.1
    before = [{"episodes": 200, "collisions": 4, "multiplier": 1.0}]  # a run from before
    assert budget_end_state(before, 0.02)["followed_collision_rate"] is None
