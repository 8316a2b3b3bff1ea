"""TensorBoard logging in one fixed tag scheme (documented in docs/training.md).

The x axis of every tag is the environment step *per client* (1 ... total_steps), so
curves of runs with different schemes, intervals or client counts line up.

| tag | value |
|---|---|
| ``rollout/ep_rew_mean`` | Fig. 4's curve as the report computes it: each client's mean
  return over its last 100 episodes, averaged over the clients, at each episode end
  (Stable-Baselines3's tag; the paper's scale, a clean pass about 6.7) |
| ``client{i}_{task}/ep_rew_mean`` | that client's mean return over its last 100 episodes |
| ``train/step_reward`` | the reward of each step averaged over the clients, then over
  windows of 100 steps (the exact series of every step is the run's ``step_rewards.npy``) |
| ``client{i}_{task}/episode_return`` | return of each finished episode, at its last step |
| ``client{i}_{task}/episode_collision`` | 1 if that episode ended in a collision, else 0 |
| ``client{i}_{task}/episode_arrived`` | 1 if it arrived |
| ``client{i}_{task}/episode_travel_time_steps`` | its length in steps |
| ``client{i}_{task}/episode_mean_speed`` | the ego's mean speed in that episode (m/s) |
| ``client{i}_{task}/episode_stopped_steps`` | steps of that episode the ego stood still |
| ``client{i}_{task}/episode_critic_bias`` | mean Q(s_t, a_t) - G_t over a terminated episode |
| ``client{i}_{task}/critic_loss`` ``actor_loss`` ``q_mean`` ``td_error`` | windows of 100 steps |
| ``client{i}_{task}/lagrange_multiplier`` ``collision_rate`` ``cost_q_mean``
  ``cost_critic_loss`` | a collision budget's lambda, the training collision rate it
  follows, and the cost critic's mean Q_c and loss; windows of 100 steps |
| ``client{i}_{task}/action``, ``policy_action`` | histograms, each round: actions driven,
  and the deterministic policy's before noise |
| ``client{i}_{task}/action_at_bounds``, ``policy_action_at_bounds`` | share at +-1
  (abs >= 0.99), windows of 100 steps |
| ``client{i}_{task}/policy_action_mean`` | the policy's mean action, windows of 100 steps |
| ``server/round`` | completed aggregation rounds, at each round's last step |
| ``server/bytes_up`` ``server/bytes_down`` | bytes up/down in that round, all clients |
| ``server/bytes_total`` | cumulative bytes up + down |
| ``server/round_time_s`` | wall time of the round |
| ``eval/{task}/{metric}``, ``eval/average/{metric}`` | test metrics, at the last step |
| ``eval/round/{task or average}/{metric}`` | the per-round test curve, each round |

plus an hparams entry (key hyperparameters against ``rollout/ep_rew_mean`` and the
``eval/average/*`` metrics).

A fleet with several vehicles per task keeps the top of the run readable: each
vehicle's tags go to a run of its own, ``vehicles/client{i}_{task}``, under the prefix
``vehicle/`` (``vehicle/ep_rew_mean``, ``vehicle/episode_return``, ...), so TensorBoard
draws one chart per tag with a line per vehicle; the run itself keeps the fleet's means:
``rollout/ep_rew_mean`` and ``tasks/{task}_ep_rew_mean`` (the mean over that task's
vehicles of each one's window).
"""

from __future__ import annotations

import math
import os
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from itertools import groupby
from pathlib import Path
from typing import Any

import numpy as np

from frl.agents.learn import EPISODE_WINDOW
from frl.episodes import METRIC_NAMES
from frl.federation.client import LOSS_NAMES, LocalUpdate

LOSS_WINDOW_STEPS = 100
AT_BOUND = 0.99
"""An action with |a| at or above this counts as saturated at the bound."""


def step_reward_tag() -> str:
    return "train/step_reward"


class TrainingLogger:
    """Writes the tag scheme above into ``log_dir``; close it (or use ``with``)."""

    def __init__(
        self,
        log_dir: str | os.PathLike[str],
        purge_step: int | None = None,
        tasks: Sequence[str] | None = None,
    ) -> None:
        """``tasks``: each vehicle's task; where one repeats (a fleet), vehicles get runs
        of their own and the run shows per-task means."""
        # Imported here so that importing frl.federation does not load tensorboard.
        from torch.utils.tensorboard import SummaryWriter

        self._summary_writer = SummaryWriter
        self.log_dir = Path(log_dir)
        self.purge_step = purge_step
        # purge_step: on resume, drop events a killed session wrote after its last checkpoint.
        self.writer = SummaryWriter(os.fspath(log_dir), purge_step=purge_step, flush_secs=30)
        self.fleet = tasks is not None and len(set(tasks)) < len(tasks)
        self._vehicle_writers: dict[str, Any] = {}

    def _vehicle(self, client: str) -> tuple[Any, str]:
        """The writer and tag prefix of a vehicle's own tags."""
        if not self.fleet:
            return self.writer, client
        writer = self._vehicle_writers.get(client)
        if writer is None:
            writer = self._summary_writer(
                os.fspath(self.log_dir / "vehicles" / client),
                purge_step=self.purge_step,
                flush_secs=30,
            )
            self._vehicle_writers[client] = writer
        return writer, "vehicle"

    def __enter__(self) -> TrainingLogger:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def log_round(
        self,
        start_step: int,
        updates: Sequence[LocalUpdate],
        round_number: int,
        bytes_up: int,
        bytes_down: int,
        bytes_total: int,
        round_time_s: float,
        recent_returns: Mapping[str, Sequence[float]] | None = None,
    ) -> None:
        """Everything about one round; steps ``start_step+1 .. start_step+num_steps``.
        ``recent_returns``: each client's last returns before this round (from the run
        state), which ``ep_rew_mean`` continues."""
        self._log_return_means(updates, recent_returns or {}, start_step)
        rewards = np.mean(np.stack([u.step_rewards for u in updates]), axis=0)
        # A point per window, not per step: one event per step was most of the roadside
        # unit's time at 80,000 steps, and TensorBoard keeps 1,000 points of a series.
        self._windows(self.writer, "train/step_reward", rewards, start_step, np.mean)
        for update in updates:
            writer, prefix = self._vehicle(update.client)
            for episode in update.episodes:
                step = run_step(update, episode.end_step, start_step)
                writer.add_scalar(f"{prefix}/episode_return", episode.episode_return, step)
                writer.add_scalar(f"{prefix}/episode_collision", float(episode.collision), step)
                writer.add_scalar(f"{prefix}/episode_arrived", float(episode.arrived), step)
                writer.add_scalar(f"{prefix}/episode_travel_time_steps", episode.steps, step)
                if episode.mean_speed is not None:
                    writer.add_scalar(f"{prefix}/episode_mean_speed", episode.mean_speed, step)
                if episode.stopped_steps is not None:
                    writer.add_scalar(
                        f"{prefix}/episode_stopped_steps", episode.stopped_steps, step
                    )
                if episode.critic_bias is not None:
                    writer.add_scalar(f"{prefix}/episode_critic_bias", episode.critic_bias, step)
            for name in LOSS_NAMES:
                values = update.losses.get(name)
                if values is not None:
                    self._windows(writer, f"{prefix}/{name}", values, start_step, np.mean)
            self._log_actions(writer, prefix, update.actions, start_step)
        writer = self.writer
        end_step = start_step + len(rewards)
        writer.add_scalar("server/round", round_number, end_step)
        writer.add_scalar("server/bytes_up", bytes_up, end_step)
        writer.add_scalar("server/bytes_down", bytes_down, end_step)
        writer.add_scalar("server/bytes_total", bytes_total, end_step)
        writer.add_scalar("server/round_time_s", round_time_s, end_step)

    def _log_return_means(
        self,
        updates: Sequence[LocalUpdate],
        recent_returns: Mapping[str, Sequence[float]],
        start_step: int,
    ) -> None:
        """``ep_rew_mean`` per client and averaged over the clients, at each step where an
        episode ended; the average once every client has ended one (as in the report).
        Vehicles left out of the round keep their windows in the average."""
        names = list(dict.fromkeys([*recent_returns, *(u.client for u in updates)]))
        windows = {
            name: deque(recent_returns.get(name, ()), maxlen=EPISODE_WINDOW) for name in names
        }
        ends = sorted(
            (run_step(update, episode.end_step, start_step), update.client, episode.episode_return)
            for update in updates
            for episode in update.episodes
        )
        for step, ended in groupby(ends, key=lambda end: end[0]):
            for _, client, episode_return in ended:
                windows[client].append(episode_return)
                mean = float(np.mean(windows[client]))
                writer, prefix = self._vehicle(client)
                writer.add_scalar(f"{prefix}/ep_rew_mean", mean, step)
            if all(windows.values()):
                average = mean_over_clients(windows.values())
                self.writer.add_scalar("rollout/ep_rew_mean", average, step)
                if self.fleet:
                    by_task: dict[str, list[deque[float]]] = {}
                    for name, window in windows.items():
                        by_task.setdefault(name.split("_", 1)[1], []).append(window)
                    for task, task_windows in by_task.items():
                        self.writer.add_scalar(
                            f"tasks/{task}_ep_rew_mean", mean_over_clients(task_windows), step
                        )

    def _log_actions(
        self, writer: Any, prefix: str, actions: Mapping[str, np.ndarray], start_step: int
    ) -> None:
        """Histograms per round and saturation per window: a policy stuck at +-1 shows."""
        end = start_step + max((len(v) for v in actions.values()), default=0)
        for series, tag in (("executed", "action"), ("policy", "policy_action")):
            values = actions.get(series)
            if values is None:
                continue
            finite = values[np.isfinite(values)]
            if finite.size:
                writer.add_histogram(f"{prefix}/{tag}", finite, end)
            self._windows(
                writer,
                f"{prefix}/{tag}_at_bounds",
                values,
                start_step,
                lambda w: np.mean(np.abs(w) >= AT_BOUND),
            )
            if series == "policy":
                self._windows(writer, f"{prefix}/policy_action_mean", values, start_step, np.mean)

    def _windows(
        self, writer: Any, tag: str, values: np.ndarray, start_step: int, statistic: Any
    ) -> None:
        """``statistic`` of the finite values of each window of LOSS_WINDOW_STEPS steps."""
        for begin in range(0, len(values), LOSS_WINDOW_STEPS):
            window = values[begin : begin + LOSS_WINDOW_STEPS]
            window = window[np.isfinite(window)]
            if window.size:
                end = start_step + min(begin + LOSS_WINDOW_STEPS, len(values))
                writer.add_scalar(tag, float(statistic(window)), end)

    def log_evaluation(
        self,
        per_task: Mapping[str, Mapping[str, Any]],
        average: Mapping[str, Any],
        step: int,
        prefix: str = "eval",
    ) -> None:
        """Test metrics as ``{prefix}/{task or average}/{metric}`` at ``step``."""
        for group, metrics in [*per_task.items(), ("average", average)]:
            for name in METRIC_NAMES:
                value = metrics.get(name)
                if value is not None and math.isfinite(value):
                    self.writer.add_scalar(f"{prefix}/{group}/{name}", value, step)

    def log_hparams(self, hparams: Mapping[str, Any], metric_tags: Sequence[str]) -> None:
        """An hparams entry in this run (not in a sub-run, as ``add_hparams`` would make),
        pointing at scalar tags already logged, so the HParams tab compares sweep runs."""
        from torch.utils.tensorboard.summary import hparams as hparams_summary
        from torch.utils.tensorboard.writer import FileWriter

        clean = {k: _hparam_value(v) for k, v in hparams.items()}
        experiment, start, end = hparams_summary(clean, dict.fromkeys(metric_tags, 0.0))
        # An event file of its own in the same directory: TensorBoard reads the
        # directory as one run.
        file_writer = FileWriter(self.writer.get_logdir())
        try:
            for summary in (experiment, start, end):
                file_writer.add_summary(summary)
        finally:
            file_writer.close()

    def flush(self) -> None:
        self.writer.flush()
        for writer in self._vehicle_writers.values():
            writer.flush()

    def close(self) -> None:
        self.writer.close()
        for writer in self._vehicle_writers.values():
            writer.close()


def run_step(update: LocalUpdate, vehicle_step: int, start_step: int) -> int:
    """A vehicle's step count on the run's axis (steps per client since the run began).

    A vehicle left out of earlier rounds has taken fewer steps than the run's axis counts;
    its step in this round is placed at the same offset from the round's start.
    """
    return start_step + vehicle_step - (update.total_steps - update.num_steps)


def _hparam_value(value: Any) -> bool | int | float | str:
    if isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (list, tuple)):
        return "x".join(str(v) for v in value) if value else "-"
    return str(value)


def mean_over_clients(windows: Iterable[Sequence[float]]) -> float:
    """``rollout/ep_rew_mean`` from each client's window of returns: the mean over the
    clients of each one's mean (so a client ending more episodes weighs no more)."""
    return float(np.mean([np.mean(window) for window in windows]))


def resume_purge_step(log_dir: str | os.PathLike[str], committed_steps: int) -> int | None:
    """The ``purge_step`` for a session that continues a run at ``committed_steps``.

    Events past the last committed round come from a killed session and are dropped, on
    resume and on a fresh start over such a session's leftovers (``resume=auto`` restarts
    a run killed before its first commit); ``None`` where there is nothing to drop.
    """
    if committed_steps or Path(log_dir).exists():
        return committed_steps + 1
    return None
