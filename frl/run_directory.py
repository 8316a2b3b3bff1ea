"""The run directory: its file names, its committed progress and where a resumed run is.

Every module that reads or writes a run asks this one (docs/training.md shows the tree):

| name | written by | content |
|---|---|---|
| ``config.yaml`` | the entry point | the resolved config the run trains with |
| ``versions.json`` | the entry point | package versions and git state (:mod:`frl.provenance`) |
| ``state.json`` | the roadside unit | :class:`RunState`: commits each finished round |
| ``step_rewards.npy`` | the roadside unit | ``train/step_reward``, one value per step |
| ``checkpoints/round_NNNN/`` | the clients | the last committed round's full client states |
| ``models/`` | the clients | final models and ``index.json`` (task -> file, or files) |
| ``results.json`` | the entry point, evaluation | training, communication and test tables |
| ``tb/`` | the roadside unit, evaluation | TensorBoard events |
| ``figure.png`` | ``python -m frl.train`` (:mod:`frl.plot`) | training and test, drawn |
| ``flower/`` | the Flower backend | SuperLink, SuperNode and ``flwr run`` logs |

Only :mod:`frl.fileio` sits below this module, so anything in frl may import it.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from frl.fileio import read_json, write_bytes_atomic, write_json_atomic

CONFIG_FILE = "config.yaml"
VERSIONS_FILE = "versions.json"
STATE_FILE = "state.json"
STEP_REWARDS_FILE = "step_rewards.npy"
CHECKPOINT_DIR = "checkpoints"
MODELS_DIR = "models"
MODEL_INDEX_FILE = "index.json"
RESULTS_FILE = "results.json"
FIGURE_FILE = "figure.png"
TB_DIR = "tb"
FLOWER_LOG_DIR = "flower"
"""Logs of the SuperLink, the SuperNodes and ``flwr run``."""
FLOWER_FAILURE_FILE = "flower_failure.json"
"""Why a Flower deployment run stopped, written by its ServerApp for the entry point."""

RESUME_ROOTS = ("outputs", "multirun")
"""Where ``resume=true`` looks for the newest unfinished run."""


class RunDirectoryError(ValueError):
    """A path is not the run directory it was taken for, or no run there can be resumed."""


def check_can_make(path: str | Path) -> None:
    """Raise :class:`RunDirectoryError` unless ``path`` is a writable directory or one that
    can be made: the nearest part of it that exists must be a writable directory.

    A read-only file system counts as not writable (``os.access`` reports it, for root too).
    """
    target = Path(path).absolute()
    existing = target
    while not existing.exists() and existing.parent != existing:
        existing = existing.parent
    if not existing.is_dir():
        raise RunDirectoryError(
            f"cannot make run directory {target}: {existing} is not a directory"
        )
    if not os.access(existing, os.W_OK | os.X_OK):
        raise RunDirectoryError(f"cannot make run directory {target}: {existing} is not writable")


@dataclass
class RunState:
    """Progress of a run, committed to ``state.json`` after every round."""

    completed_rounds: int = 0
    steps_per_client: int = 0
    checkpoint: str | None = None
    """Directory (relative to the run) of the last round's client checkpoints."""
    training_finished: bool = False
    bytes_per_upload: int = 0
    bytes_per_download: int = 0
    total_bytes_up: int = 0
    total_bytes_down: int = 0
    uploads: int = 0
    downloads: int = 0
    episodes: dict[str, int] = field(default_factory=dict)
    collisions: dict[str, int] = field(default_factory=dict)
    arrivals: dict[str, int] = field(default_factory=dict)
    last_returns: dict[str, float] = field(default_factory=dict)
    recent_returns: dict[str, list[float]] = field(default_factory=dict)
    """Each client's last 100 training-episode returns, oldest first: the window of
    ``rollout/ep_rew_mean``, kept so that a resumed run's curve goes on exactly."""
    wall_time_s: float = 0.0
    """Seconds of the round loop, summed over sessions when resumed."""
    local_training_s: float = 0.0
    """Seconds the roadside unit waited for local training (the clients' work)."""
    client_cpu_s: float = 0.0
    """CPU seconds of local training, summed over clients (independent of machine load)."""
    client_training_s: float = 0.0
    """Wall seconds of local training of the slowest client of each round, summed over
    rounds: the part of a round no transport can save."""
    aggregation_s: float = 0.0
    communication_s: float = 0.0
    """Seconds spent sending the global model down (pickling and pipes)."""
    checkpoint_s: float = 0.0
    logging_s: float = 0.0
    round_times_s: list[float] = field(default_factory=list)
    dropped_clients: dict[str, str] = field(default_factory=dict)
    """Clients dropped after a failure (Flower backend, ``accept_failures``): name -> why."""
    vehicle_steps: dict[str, int] = field(default_factory=dict)
    """Environment steps each vehicle has taken; below ``steps_per_client`` for a vehicle
    left out of some rounds (``federation.fraction_train``)."""
    participants: list[list[str]] = field(default_factory=list)
    """The vehicles that trained in each round (recorded only where rounds draw a part)."""
    round_tests: list[dict[str, Any]] = field(default_factory=list)
    """The per-round test curve (``round_test_episodes``): after each round, ``{"step",
    "per_task", "average"}`` of the deployed model on the round-test seeds."""
    round_test_s: float = 0.0
    """Seconds the round tests took, summed over rounds (inside ``wall_time_s``)."""
    budget_rounds: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    """Each vehicle's rounds as the collision budget counts them: episodes, collisions and
    the multiplier at the round's end (:func:`frl.federation.collision_budget.round_record`)."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunState:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})

    @property
    def coordinator_overhead_s(self) -> float:
        """Wall time not spent in local training: aggregation, transfers, logging, checkpoints."""
        return max(0.0, self.wall_time_s - self.local_training_s)


RoundHook = Callable[[RunState], None]
"""Called with the state after each committed round (tests use it to simulate a kill)."""


# ------------------------------------------------------------------ state
def read_state(run_dir: Path) -> RunState | None:
    """The run's last committed state; None before its first commit.

    Raises:
        RunDirectoryError: the state file is there but unreadable (not JSON, or no
            object), naming the file. frl writes it atomically, so this is damage done
            outside frl.
    """
    path = Path(run_dir) / STATE_FILE
    if not path.exists():
        return None
    try:
        data = read_json(path)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise RunDirectoryError(f"{path}: not a readable run state ({error})") from None
    if not isinstance(data, dict):
        raise RunDirectoryError(f"{path}: not a readable run state (no JSON object)")
    return RunState.from_dict(data)


def write_state(run_dir: Path, state: RunState) -> None:
    """Commit ``state`` atomically."""
    write_json_atomic(Path(run_dir) / STATE_FILE, state.to_dict())


def read_step_rewards(run_dir: Path, steps: int | None = None) -> np.ndarray:
    """``train/step_reward`` as saved; only the first ``steps`` (the committed part) if given.

    A killed session may have written past its last commit.
    """
    path = Path(run_dir) / STEP_REWARDS_FILE
    if steps == 0 or not path.exists():
        return np.zeros(0, np.float32)
    return np.load(path)[:steps].astype(np.float32)


def write_step_rewards(run_dir: Path, step_rewards: np.ndarray) -> None:
    buffer = io.BytesIO()
    np.save(buffer, step_rewards)
    write_bytes_atomic(Path(run_dir) / STEP_REWARDS_FILE, buffer.getvalue())


def relative_path(path: Path, root: Path) -> str:
    """``path`` relative to ``root`` (a run or vehicle state directory), as vehicles get it."""
    try:
        return str(Path(path).resolve().relative_to(Path(root).resolve()))
    except ValueError:
        raise ValueError(f"{path} lies outside {root}") from None


SERVER_STATE_FILE = "server.pt"
"""In a round's checkpoint directory: the roadside unit's global model and strategy state,
where the run needs them to resume (a server-side optimiser, or rounds that draw a part
of the fleet)."""


def checkpoint_dir(completed_rounds: int) -> str:
    """Where the clients' states after round ``completed_rounds`` go, relative to the run."""
    return f"{CHECKPOINT_DIR}/round_{completed_rounds:04d}"


# ------------------------------------------------------------------ results
def read_results(run_dir: Path) -> dict[str, Any] | None:
    path = Path(run_dir) / RESULTS_FILE
    return read_json(path) if path.exists() else None


def write_results(run_dir: Path, results: dict[str, Any]) -> None:
    write_json_atomic(Path(run_dir) / RESULTS_FILE, results)


def merge_evaluation(run_dir: Path, evaluation: dict[str, Any]) -> None:
    """Put ``evaluation`` into the run's ``results.json``, keeping everything else."""
    results = read_results(run_dir) or {}
    results["evaluation"] = evaluation
    write_results(run_dir, results)


def read_saved_config(run_dir: Path) -> dict[str, Any]:
    """``config.yaml`` as plain data; :class:`RunDirectoryError` if ``run_dir`` has none.

    The checked, migrated config is :func:`frl.train_config.load_run_config`.
    """
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise RunDirectoryError(f"{run_dir} is not an frl run directory: it has no {CONFIG_FILE}")
    try:  # OmegaConf's YAML reads 1e-4 as a number, as it wrote it
        saved = OmegaConf.to_container(OmegaConf.load(path), resolve=True)
    except (yaml.YAMLError, OmegaConfBaseException) as error:
        raise RunDirectoryError(f"{path} is not a readable config: {error}") from None
    if not isinstance(saved, dict):
        raise RunDirectoryError(f"{path} is not an frl run config")
    return saved


def model_files(run_dir: Path) -> dict[str, list[Path]]:
    """Each task's model file(s) (``models/index.json``: one, or Sep-DDPG's per vehicle
    of a fleet); ``FileNotFoundError`` if absent."""
    index = Path(run_dir) / MODELS_DIR / MODEL_INDEX_FILE
    if not index.is_file():
        raise FileNotFoundError(
            f"{run_dir} has no {MODELS_DIR}/{MODEL_INDEX_FILE}: training has not finished "
            "(resume it with `python -m frl.train resume=RUN_DIR`)"
        )
    models = Path(run_dir) / MODELS_DIR
    return {
        task: [models / name for name in ([names] if isinstance(names, str) else names)]
        for task, names in read_json(index).items()
    }


# ------------------------------------------------------------------ resume
def is_resumable(run_dir: Path) -> bool:
    """The run there has committed a round, and its training or evaluation is unfinished."""
    run_dir = Path(run_dir)
    state = read_state(run_dir)
    if state is None or not (run_dir / CONFIG_FILE).exists():
        return False
    if not state.training_finished:
        return True
    if not read_saved_config(run_dir).get("eval_episodes"):
        return False
    results = read_results(run_dir)
    return not (results is not None and "evaluation" in results)


def is_finished(run_dir: Path) -> bool:
    """Training and any configured evaluation of the run in ``run_dir`` are done."""
    state = read_state(run_dir)
    if state is None or not state.training_finished or is_resumable(run_dir):
        return False
    results = read_results(run_dir)
    if results is None:
        return False
    config = read_saved_config(run_dir) if (Path(run_dir) / CONFIG_FILE).is_file() else {}
    return evaluation_done(results, config)


def evaluation_done(results: dict[str, Any], config: dict[str, Any]) -> bool:
    """The test a run's ``config`` asks for (``eval_episodes`` > 0) is in its ``results``.

    A test that failed or was stopped leaves results without "evaluation": resuming the
    run tests it then, without training again.
    """
    return "evaluation" in results or not config.get("eval_episodes", 0)


def newest_resumable(roots: Iterable[str | Path], exclude: Path | None = None) -> Path | None:
    """The most recently committed resumable run under ``roots``; None if there is none."""
    candidates = [
        path.parent
        for root in roots
        for path in Path(root).glob(f"**/{STATE_FILE}")
        if (exclude is None or path.parent.resolve() != exclude.resolve())
        and is_resumable(path.parent)
    ]
    return max(candidates, key=lambda p: (p / STATE_FILE).stat().st_mtime, default=None)


def is_auto(resume: Any) -> bool:
    """Whether the ``resume`` key is ``auto``: continue, skip or start the run there."""
    return isinstance(resume, str) and resume.lower() == "auto"


def names_a_run(resume: Any) -> bool:
    """Whether the ``resume`` key names a run directory (not false, true or ``auto``)."""
    return isinstance(resume, str) and resume.lower() not in ("true", "false", "auto")


def resolve(resume: Any, configured: str | Path | None, default: Path | None) -> tuple[Path, bool]:
    """The directory a run writes into, and whether it holds a run to resume (or skip).

    Args:
        resume: the ``resume`` key: false, true, ``"auto"`` or a run directory.
        configured: the ``run_dir`` key (None: ``default``).
        default: Hydra's output directory, if Hydra runs.

    Raises:
        RunDirectoryError: nothing to resume where asked, or a run already there.
    """
    if names_a_run(resume):
        run_dir = Path(resume).expanduser()
        if read_state(run_dir) is None:
            stopped_early = (run_dir / CONFIG_FILE).is_file()
            raise RunDirectoryError(
                f"resume={resume}: no checkpointed run there (no {STATE_FILE})"
                + (
                    "; it stopped before its first round was committed: start it again "
                    f"with run_dir={resume} resume=auto"
                    if stopped_early
                    else ""
                )
            )
        return run_dir, True
    run_dir = Path(configured) if configured else default
    if run_dir is None:
        raise RunDirectoryError("run_dir must be set when frl trains outside Hydra")
    if is_auto(resume):  # deterministic sweep dirs: continue, skip or start the run there
        return run_dir, read_state(run_dir) is not None and (run_dir / CONFIG_FILE).exists()
    if resume is True or (isinstance(resume, str) and resume.lower() == "true"):
        if is_resumable(run_dir):
            return run_dir, True
        newest = newest_resumable(RESUME_ROOTS, exclude=run_dir)
        if newest is None:
            raise RunDirectoryError(
                f"resume=true: no unfinished run under {', '.join(RESUME_ROOTS)}/; "
                "pass resume=RUN_DIR"
            )
        return newest, True
    if read_state(run_dir) is not None:
        raise RunDirectoryError(
            f"{run_dir} already holds a run; pass resume=true to continue it or another run_dir"
        )
    return run_dir, False
