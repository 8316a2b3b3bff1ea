"""The report's statistics against hand-computed numbers."""

import math

import numpy as np
import pytest

from frl.report.stats import (
    band,
    episode_return_curve,
    first_crossing,
    first_hold,
    mean_ci,
    moving_average,
    t_quantile,
    wilson_interval,
)


@pytest.mark.parametrize(
    ("df", "expected"),
    [(1, 12.706205), (2, 4.302653), (3, 3.182446), (4, 2.776445), (9, 2.262157), (30, 2.042272)],
)
def test_t_quantile_matches_the_tables(df, expected):
    assert t_quantile(0.975, df) == pytest.approx(expected, abs=1e-5)


def test_the_wilson_interval_by_hand():
    # 5 of 100: centre (p + z^2/2n) / (1 + z^2/n), half-width
    # z sqrt(p(1-p)/n + z^2/4n^2) / (1 + z^2/n), z = 1.959964
    z, n, p = 1.959964, 100, 0.05
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    low, high = wilson_interval(5, 100)
    assert (low, high) == pytest.approx((centre - half, centre + half), abs=1e-6)
    # none of 300: [0, (z^2/n) / (1 + z^2/n)], not the Wald interval's empty [0, 0]
    none_low, none_high = wilson_interval(0, 300)
    assert none_low == 0.0 and none_high == pytest.approx((z * z / 300) / (1 + z * z / 300))
    assert all(math.isnan(x) for x in wilson_interval(0, 0))


def test_mean_ci_is_the_t_interval_over_seeds():
    estimate = mean_ci([1.0, 2.0, 3.0, 4.0])

    # s = sqrt(5/3), half = t(0.975, 3) * s / sqrt(4)
    assert estimate.mean == 2.5
    assert estimate.half_width == pytest.approx(3.182446 * math.sqrt(5 / 3) / 2, rel=1e-6)
    assert estimate.n == 4
    assert estimate.low == pytest.approx(2.5 - estimate.half_width)


def test_mean_ci_of_one_seed_has_no_interval_and_of_none_raises():
    assert mean_ci([7.0]).half_width is None
    assert mean_ci([7.0]).low is None
    with pytest.raises(ValueError, match="no values"):
        mean_ci([])


def test_band_per_step():
    mean, half = band(np.array([[0.0, 2.0], [2.0, 2.0]]))

    np.testing.assert_allclose(mean, [1.0, 2.0])
    # step 1: s = sqrt(2), half = 12.706205 * sqrt(2) / sqrt(2); step 2: s = 0
    np.testing.assert_allclose(half, [12.706205, 0.0], atol=1e-5)
    assert np.isnan(band(np.array([[1.0, 2.0]]))[1]).all()


def test_moving_average_is_trailing():
    np.testing.assert_allclose(moving_average(np.array([1, 2, 3, 4]), 2), [1, 1.5, 2.5, 3.5])
    np.testing.assert_allclose(moving_average(np.array([1, 2, 3]), 10), [1, 1.5, 2])
    with pytest.raises(ValueError):
        moving_average(np.array([1.0]), 0)


def test_episode_return_curve_is_the_trailing_mean_of_ended_episodes():
    curve = episode_return_curve(np.array([3, 5, 9]), np.array([1.0, 2.0, 6.0]), 10, window=2)

    assert np.isnan(curve[:2]).all()
    np.testing.assert_allclose(curve[2:], [1, 1, 1.5, 1.5, 1.5, 1.5, 4, 4])


def test_first_crossing_is_one_based_and_none_if_never():
    assert first_crossing(np.array([np.nan, 5.0, 6.0, 7.0]), 6.0) == 3
    assert first_crossing(np.array([1.0, 2.0]), 6.0) is None


def test_first_crossing_counts_only_steps_after_the_given_one():
    curve = np.array([6.0, 1.0, 6.5, 7.0])
    assert first_crossing(curve, 6.0, after=1) == 3
    assert first_crossing(curve, 6.0, after=3) == 4
    assert first_crossing(curve, 6.0, after=4) is None


def test_first_hold_is_the_step_from_which_the_curve_stays_at_the_threshold():
    steps = [2, 4, 6, 8]
    assert first_hold(steps, [6.1, 5.9, 6.2, 6.0], 6.0) == 6  # 6.0 itself holds
    assert first_hold(steps, [6.1, 6.2, 6.3, 7.0], 6.0) == 2
    assert first_hold(steps, [6.1, 6.2, 6.3, 5.0], 6.0) is None  # ends below
    assert first_hold(steps, [6.1, np.nan, 6.3, 6.4], 6.0) == 6  # NaN is no hold
    assert first_hold([], [], 6.0) is None
