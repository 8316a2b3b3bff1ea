"""Exploration noise: OU mean reversion and exact stationary variance; own generators."""

import numpy as np
import pytest

from frl.agents import GaussianNoise, OrnsteinUhlenbeckNoise, make_noise


def test_ou_without_diffusion_decays_geometrically_to_its_mean() -> None:
    noise = OrnsteinUhlenbeckNoise((2,), np.random.default_rng(0), theta=0.5, sigma=0.0, dt=0.1)
    noise.state = np.array([4.0, -2.0])
    for step in range(1, 6):
        value = noise()
        # x_n = mu + (1 - theta dt)^n (x_0 - mu) with mu = 0
        np.testing.assert_allclose(value, 0.95**step * np.array([4.0, -2.0]))


def test_ou_stationary_mean_and_variance_match_the_discretisation() -> None:
    theta, sigma, dt = 0.15, 0.3, 1.0  # a = 0.85: mixes in tens of steps
    paths = 20_000
    noise = OrnsteinUhlenbeckNoise((paths,), np.random.default_rng(1), theta, sigma, dt, mu=0.5)
    noise.state[:] = 3.0  # start far from the mean: it must revert
    for _ in range(150):  # 0.85**150 ~ 3e-11: the start is forgotten
        samples = noise()
    a = 1 - theta * dt
    exact = sigma**2 * dt / (1 - a**2)
    assert noise.stationary_variance == pytest.approx(exact)
    # Independent paths: standard error of the mean sqrt(var/n) ~ 0.0033, of the
    # variance var*sqrt(2/n) ~ 1 %. Tolerances are about 5 standard errors.
    assert samples.mean() == pytest.approx(0.5, abs=0.02)
    assert samples.var() == pytest.approx(exact, rel=0.05)
    # Continuous-time limit sigma^2 / (2 theta) is 11 % off at this dt: the test can tell.
    assert abs(samples.var() - sigma**2 / (2 * theta)) > 0.05 * exact


def test_ou_is_autocorrelated_with_lag_one_coefficient_a() -> None:
    noise = OrnsteinUhlenbeckNoise((20_000,), np.random.default_rng(2), 0.15, 0.3, 1.0)
    for _ in range(150):
        noise()
    x0 = noise()
    x1 = noise()
    assert np.corrcoef(x0, x1)[0, 1] == pytest.approx(0.85, abs=0.02)


def test_ou_reset_returns_to_mean_and_state_dict_round_trips() -> None:
    noise = OrnsteinUhlenbeckNoise((3,), np.random.default_rng(3), mu=0.25)
    for _ in range(10):
        noise()
    saved = noise.state_dict()
    expected = [noise() for _ in range(3)]
    noise.load_state_dict(saved)
    np.testing.assert_array_equal([noise() for _ in range(3)], expected)
    noise.reset()
    np.testing.assert_array_equal(noise.state, np.full(3, 0.25))


def test_gaussian_noise_scale_and_own_generator() -> None:
    before = np.random.get_state()[1].copy()
    samples = GaussianNoise((50_000,), np.random.default_rng(4), sigma=0.2)()
    assert samples.std() == pytest.approx(0.2, rel=0.02)
    np.testing.assert_array_equal(np.random.get_state()[1], before)  # global RNG untouched


def test_same_generator_seed_same_noise_and_unknown_kind_raises() -> None:
    a = make_noise("ou", (2,), np.random.default_rng(5), sigma=0.3)
    b = make_noise("ou", (2,), np.random.default_rng(5), sigma=0.3)
    np.testing.assert_array_equal([a() for _ in range(5)], [b() for _ in range(5)])
    with pytest.raises(ValueError, match="unknown noise"):
        make_noise("pink", (2,), np.random.default_rng(0), sigma=0.1)
