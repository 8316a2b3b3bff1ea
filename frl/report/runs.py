"""Read finished runs, from a run directory or from its exported result files, and export.

A run directory (docs/training.md) holds ``results.json``, ``config.yaml``, every step's
reward in ``step_rewards.npy`` and TensorBoard events under ``tb/``, where each client's
training episodes are ``client{i}_{task}/episode_*`` (runs written before the array logged
every step's reward as ``train/step_reward``). :func:`export_run` writes the small
files the report needs into a data directory, so figures can be re-plotted without the run:

| file | content |
|---|---|
| ``results.json`` | the run's results (seed, wall times, git commit, evaluation, bytes) |
| ``config.yaml`` | its resolved config (reward weights, interval, agent) |
| ``step_rewards.csv`` | ``step,reward``: ``train/step_reward`` |
| ``episodes.csv`` | ``client,end_step,return,collision,arrived,steps``: every training episode |
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from frl.fileio import read_json, write_bytes_atomic, write_json_atomic
from frl.run_directory import (
    CONFIG_FILE,
    RESULTS_FILE,
    STATE_FILE,
    TB_DIR,
    VERSIONS_FILE,
    evaluation_done,
)
from frl.run_directory import STEP_REWARDS_FILE as STEP_REWARDS_NPY

STEP_REWARDS_CSV = "step_rewards.csv"
EPISODES_CSV = "episodes.csv"
STEP_REWARD_TAG = "train/step_reward"
EPISODE_FIELDS = ("return", "collision", "arrived", "steps")
_EPISODE_TAGS = {
    "return": "episode_return",
    "collision": "episode_collision",
    "arrived": "episode_arrived",
    "steps": "episode_travel_time_steps",
}


class RunDataError(ValueError):
    """A directory does not hold what the report needs; the message says what is missing."""


@dataclass(frozen=True)
class Episodes:
    """One client's training episodes, in the order they ended."""

    end_step: np.ndarray
    returns: np.ndarray
    collision: np.ndarray
    arrived: np.ndarray
    steps: np.ndarray


@dataclass(frozen=True)
class RunRecord:
    """What the report uses of one run."""

    path: Path
    results: dict[str, Any]
    config: dict[str, Any]
    step_rewards: np.ndarray
    """``train/step_reward`` at steps 1..len."""
    episodes: dict[str, Episodes] = field(default_factory=dict)
    """Per client name (``client0_left``)."""

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def scheme(self) -> str:
        return str(self.results["scheme"])

    @property
    def seed(self) -> int:
        return int(self.results["seed"])

    @property
    def interval(self) -> int:
        return int(self.results["interval"])

    @property
    def total_steps(self) -> int:
        return int(self.results["total_steps"])

    @property
    def evaluation(self) -> dict[str, Any] | None:
        return self.results.get("evaluation")

    @property
    def round_test_curve(self) -> tuple[list[int], list[float]] | None:
        """The per-round test curve (``round_test_episodes``): each round's last step and
        the deployed model's mean test return there; None for a run without it."""
        return self.round_test_metric("average_reward")

    def round_test_metric(self, metric: str) -> tuple[list[int], list[float]] | None:
        """Each round's last step and the deployed model's ``metric`` there, averaged over
        the tasks (NaN where a point lacks it); None for a run without the curve."""
        points = (self.results.get("round_tests") or {}).get("points") or []
        if not points:
            return None
        values = [point["average"].get(metric) for point in points]
        return [int(p["step"]) for p in points], [math.nan if v is None else v for v in values]

    @property
    def round_test_yardsticks(self) -> dict[str, dict[str, Any]]:
        """The yardsticks tested on the per-round test curve's own seeds, ``{name:
        {"per_task", "average"}}``; empty for a run without them."""
        return (self.results.get("round_tests") or {}).get("yardsticks") or {}

    @property
    def round_test_episodes(self) -> int | None:
        """Episodes per task of each per-round test; None for a run without the curve."""
        return (self.results.get("round_tests") or {}).get("episodes_per_task")

    @property
    def reward(self) -> dict[str, Any]:
        return dict(self.config.get("reward", {}))

    @property
    def git_commit(self) -> str | None:
        return (self.results.get("versions") or {}).get("git_commit")

    @property
    def learning_starts(self) -> int:
        """Steps of warm-up before the agents' first update (0 if the config has none)."""
        return int((self.config.get("agent") or {}).get("learning_starts", 0))

    @property
    def wall_time_s(self) -> float | None:
        """Training plus test time. Training time is summed over every session of a resumed
        run; the job's own wall time would count only the last session."""
        training = self.results.get("training", {}).get("wall_time_s")
        if training is None:
            return self.results.get("job_wall_time_s")
        return training + self.results.get("evaluation_wall_time_s", 0.0)


def has_complete_results(run_dir: Path) -> bool:
    """The run's results say training finished and, if its config asks for it, the test
    too. Unlike ``run_directory.is_finished`` it needs no ``state.json``, so runs saved by
    older frl versions count as well."""
    results_path = run_dir / RESULTS_FILE
    if not results_path.exists():
        return False
    results = read_json(results_path)
    training = results.get("training", {})
    if training.get("steps_per_client") != results.get("total_steps"):
        return False
    state_path = run_dir / STATE_FILE
    if state_path.exists() and not read_json(state_path).get("training_finished"):
        return False
    return evaluation_done(results, read_config(run_dir))


def load_run(path: str | os.PathLike[str]) -> RunRecord:
    """A run from a run directory (TensorBoard) or a data directory (CSV files)."""
    path = Path(path)
    if not (path / RESULTS_FILE).exists():
        raise RunDataError(f"{path}: no {RESULTS_FILE}")
    results = read_json(path / RESULTS_FILE)
    config = read_config(path)
    if (path / STEP_REWARDS_CSV).exists():
        step_rewards, episodes = _read_csvs(path)
    elif (path / TB_DIR).is_dir():
        # step_rewards.npy holds every step's reward; TensorBoard holds 100-step means
        # (every step in runs written before, the same values as the array's).
        has_array = (path / STEP_REWARDS_NPY).exists()
        step_rewards, episodes = _read_tensorboard(path / TB_DIR, step_rewards=not has_array)
        if has_array:
            step_rewards = np.load(path / STEP_REWARDS_NPY).astype(float)
    else:
        raise RunDataError(f"{path}: neither {STEP_REWARDS_CSV} nor TensorBoard events ({TB_DIR}/)")
    return RunRecord(path, results, config, step_rewards, episodes)


def exported_results(run_dir: Path) -> dict[str, Any]:
    """The run's ``results.json`` as exported, with the versions it trained with.

    Runs made before ``results.json`` recorded ``versions.json`` carry the versions (git
    commit) of the moment they finished, which may be later than the code that trained.
    """
    results = read_json(run_dir / RESULTS_FILE)
    if (run_dir / VERSIONS_FILE).exists():
        results["versions"] = read_json(run_dir / VERSIONS_FILE)
    return results


def export_run(run_dir: str | os.PathLike[str], target: str | os.PathLike[str]) -> Path:
    """Write the run's small result files into ``target`` (created); return it."""
    run_dir, target = Path(run_dir), Path(target)
    if not has_complete_results(run_dir):
        raise RunDataError(f"{run_dir}: not a finished run")
    record = load_run(run_dir)
    write_json_atomic(target / RESULTS_FILE, exported_results(run_dir))
    write_bytes_atomic(
        target / CONFIG_FILE, yaml.safe_dump(record.config, sort_keys=False).encode()
    )
    rows = [("step", "reward")]
    rows += [(str(i), f"{v:.7g}") for i, v in enumerate(record.step_rewards.tolist(), start=1)]
    write_bytes_atomic(target / STEP_REWARDS_CSV, _csv(rows))
    rows = [("client", "end_step", *EPISODE_FIELDS)]
    for client, ep in sorted(record.episodes.items()):
        for i in range(ep.end_step.size):
            rows.append(
                (
                    client,
                    str(int(ep.end_step[i])),
                    f"{ep.returns[i]:.7g}",
                    str(int(ep.collision[i])),
                    str(int(ep.arrived[i])),
                    str(int(ep.steps[i])),
                )
            )
    write_bytes_atomic(target / EPISODES_CSV, _csv(rows))
    return target


# ------------------------------------------------------------------ readers
def read_config(path: Path) -> dict[str, Any]:
    """A run directory's resolved config ({} without one)."""
    config_path = path / CONFIG_FILE
    if not config_path.exists():
        return {}
    return yaml.safe_load(config_path.read_text()) or {}


def _csv(rows: list[tuple[str, ...]]) -> bytes:
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerows(rows)
    return buffer.getvalue().encode()


def _read_csvs(path: Path) -> tuple[np.ndarray, dict[str, Episodes]]:
    with (path / STEP_REWARDS_CSV).open() as f:
        rows = list(csv.DictReader(f))
    steps = np.array([int(r["step"]) for r in rows], dtype=int)
    if not np.array_equal(steps, np.arange(1, steps.size + 1)):
        raise RunDataError(f"{path / STEP_REWARDS_CSV}: steps are not 1, 2, 3, ...")
    step_rewards = np.array([float(r["reward"]) for r in rows])
    columns: dict[str, dict[str, list[float]]] = {}
    if (path / EPISODES_CSV).exists():
        with (path / EPISODES_CSV).open() as f:
            for r in csv.DictReader(f):
                client = columns.setdefault(
                    r["client"], {k: [] for k in ("end_step", *EPISODE_FIELDS)}
                )
                for key in client:
                    client[key].append(float(r[key]))
    return step_rewards, {name: _episodes(c) for name, c in columns.items()}


def _episodes(columns: dict[str, list[float]]) -> Episodes:
    return Episodes(
        end_step=np.asarray(columns["end_step"], dtype=int),
        returns=np.asarray(columns["return"], dtype=float),
        collision=np.asarray(columns["collision"], dtype=int),
        arrived=np.asarray(columns["arrived"], dtype=int),
        steps=np.asarray(columns["steps"], dtype=int),
    )


def _read_tensorboard(
    tb_dir: Path, step_rewards: bool = True
) -> tuple[np.ndarray, dict[str, Episodes]]:
    """The step rewards (empty unless ``step_rewards``: a run written before
    ``step_rewards.npy`` logged every step) and each client's episodes; a fleet's vehicles
    each have a run of their own under ``vehicles/`` (tags ``vehicle/...``), the others sit
    in the run's."""
    accumulator = _accumulator(tb_dir)
    tags = set(accumulator.Tags().get("scalars", []))
    rewards = np.zeros(0)
    if step_rewards and STEP_REWARD_TAG in tags:
        steps, values = _series(accumulator, STEP_REWARD_TAG)
        if not np.array_equal(steps, np.arange(1, steps.size + 1)):
            raise RunDataError(f"{tb_dir}: {STEP_REWARD_TAG} misses steps")
        rewards = values
    episodes: dict[str, Episodes] = {}
    clients = sorted({t.split("/")[0] for t in tags if t.endswith(f"/{_EPISODE_TAGS['return']}")})
    for client in clients:
        episodes[client] = _client_episodes(accumulator, tags, client, tb_dir)
    vehicles = tb_dir / "vehicles"
    for run in sorted(vehicles.iterdir()) if vehicles.is_dir() else []:
        own = _accumulator(run)
        episodes[run.name] = _client_episodes(
            own, set(own.Tags().get("scalars", [])), "vehicle", run
        )
    return rewards, episodes


def _accumulator(directory: Path) -> Any:
    # EventAccumulator applies the purge a resumed session writes (frl.train's purge_step).
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    accumulator = EventAccumulator(os.fspath(directory), size_guidance={"scalars": 0})
    accumulator.Reload()
    return accumulator


def _series(accumulator: Any, tag: str) -> tuple[np.ndarray, np.ndarray]:
    # Keep the last value written at each step, in step order.
    by_step = {event.step: event.value for event in accumulator.Scalars(tag)}
    steps = np.array(sorted(by_step), dtype=int)
    return steps, np.array([by_step[s] for s in steps.tolist()], dtype=float)


def _client_episodes(accumulator: Any, tags: set[str], prefix: str, where: Path) -> Episodes:
    columns: dict[str, Any] = {}
    end_steps, columns["return"] = _series(accumulator, f"{prefix}/{_EPISODE_TAGS['return']}")
    for key in ("collision", "arrived", "steps"):
        tag = f"{prefix}/{_EPISODE_TAGS[key]}"
        steps, values = (
            _series(accumulator, tag) if tag in tags else (end_steps, np.zeros(end_steps.size))
        )
        if not np.array_equal(steps, end_steps):
            raise RunDataError(f"{where}: {tag} does not match the episode returns")
        columns[key] = values
    columns["end_step"] = end_steps
    return _episodes(columns)
