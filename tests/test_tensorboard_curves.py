"""TensorBoard's ``rollout/ep_rew_mean`` is Fig. 4's curve exactly as the report computes it."""

from __future__ import annotations

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from frl.episodes import EpisodeRecord
from frl.federation.client import LocalUpdate
from frl.federation.tensorboard import EPISODE_WINDOW, TrainingLogger
from frl.report.stats import episode_return_curve


def _update(client: str, start: int, steps: int, ends: list[tuple[int, float]]) -> LocalUpdate:
    episodes = [
        EpisodeRecord("left", ret, False, True, False, 10, end_step=end) for end, ret in ends
    ]
    return LocalUpdate(client, steps, start + steps, np.zeros(steps, np.float32), episodes)


def _scalars(log_dir) -> dict[str, list[tuple[int, float]]]:
    accumulator = EventAccumulator(str(log_dir), size_guidance={"scalars": 0})
    accumulator.Reload()
    return {
        tag: [(e.step, e.value) for e in accumulator.Scalars(tag)]
        for tag in accumulator.Tags()["scalars"]
    }


def test_ep_rew_mean_continues_the_windows_of_earlier_rounds_and_matches_the_report(tmp_path):
    rng = np.random.default_rng(0)
    # client a ends 130 episodes before this round (more than the window), b ends 3
    before_a = [(step + 1, float(r)) for step, r in enumerate(rng.normal(3, 2, 130))]
    before_b = [(40, 1.0), (80, 2.0), (120, 4.0)]
    now_a = [(135, 6.0), (140, -2.0), (150, 5.0)]
    now_b = [(140, 7.0), (149, 6.5)]
    recent = {"a": [r for _, r in before_a][-EPISODE_WINDOW:], "b": [r for _, r in before_b]}
    updates = [_update("a", 130, 20, now_a), _update("b", 130, 20, now_b)]
    with TrainingLogger(tmp_path) as logger:
        logger.log_round(130, updates, 1, 0, 0, 0, 1.0, recent_returns=recent)

    scalars = _scalars(tmp_path)
    curves = {
        name: episode_return_curve(
            np.array([s for s, _ in ends]), np.array([r for _, r in ends]), 150, EPISODE_WINDOW
        )
        for name, ends in (("a", before_a + now_a), ("b", before_b + now_b))
    }
    for name in ("a", "b"):
        logged = scalars[f"{name}/ep_rew_mean"]
        assert [step for step, _ in logged] == [s for s, _ in (now_a if name == "a" else now_b)]
        for step, value in logged:  # TensorBoard stores float32
            assert value == pytest.approx(curves[name][step - 1], rel=1e-6, abs=1e-6)
    average = scalars["rollout/ep_rew_mean"]
    assert [step for step, _ in average] == [135, 140, 149, 150]  # both ended at step 140
    for step, value in average:
        expected = (curves["a"][step - 1] + curves["b"][step - 1]) / 2
        assert value == pytest.approx(expected, rel=1e-6, abs=1e-6)


def test_the_average_waits_for_every_client_to_end_an_episode(tmp_path):
    updates = [_update("a", 0, 50, [(10, 5.0), (30, 6.0)]), _update("b", 0, 50, [(40, 1.0)])]
    with TrainingLogger(tmp_path) as logger:
        logger.log_round(0, updates, 1, 0, 0, 0, 1.0)
        logger.log_hparams({"seed": 0}, ["rollout/ep_rew_mean"])

    scalars = _scalars(tmp_path)
    assert scalars["rollout/ep_rew_mean"] == [(40, pytest.approx(3.25))]  # (5.5 + 1) / 2
    assert [step for step, _ in scalars["a/ep_rew_mean"]] == [10, 30]
