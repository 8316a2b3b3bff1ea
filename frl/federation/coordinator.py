"""The roadside unit: drives rounds, aggregates with :func:`fedavg`, logs and checkpoints.

One round (Section III.C, Fig. 2):

1. every client trains ``interval`` environment steps locally, in parallel;
2. ``fedavg`` only: the clients upload their models, the roadside unit averages them
   (Eq. (3)) and sends the global model back to every client;
3. the round is logged and checkpointed: every client's full state (agent, replay
   buffer, optimizer, noise, generators), then ``state.json``, which commits the round.

A run killed at any point resumes from the last committed round with nothing before it
lost; the episode that was running at the kill is dropped, since SUMO's state is not
checkpointed (the next step starts a fresh simulation with a new seed).
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from frl.federation.fedavg import fedavg, state_nbytes
from frl.federation.plan import FederationPlan
from frl.federation.pool import ClientPool
from frl.federation.tensorboard import TrainingLogger
from frl.fileio import write_bytes_atomic, write_json_atomic

STATE_FILE = "state.json"
STEP_REWARDS_FILE = "step_rewards.npy"
CHECKPOINT_DIR = "checkpoints"
MODELS_DIR = "models"
MODEL_INDEX_FILE = "index.json"


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


class Coordinator:
    """Runs the rounds of ``plan`` over ``clients``, writing into ``run_dir``.

    Args:
        plan: scheme, budget and interval.
        clients: a started :class:`ClientPool`.
        run_dir: where checkpoints, models and ``state.json`` go.
        logger: TensorBoard logger, or None.
        progress: show a progress bar over the run.
        on_round_end: called after each committed round (tests use it to simulate a kill).
    """

    def __init__(
        self,
        plan: FederationPlan,
        clients: ClientPool,
        run_dir: Path,
        logger: TrainingLogger | None = None,
        progress: bool = False,
        on_round_end: RoundHook | None = None,
    ) -> None:
        self.plan = plan
        self.clients = clients
        self.run_dir = Path(run_dir)
        self.logger = logger
        self.progress = progress
        self.on_round_end = on_round_end

    def run(self, state: RunState) -> RunState:
        """Train from ``state`` (fresh or loaded) to the end of the budget; return the state."""
        plan, clients = self.plan, self.clients
        if state.checkpoint is not None and not state.training_finished:
            clients.load(self.run_dir / state.checkpoint)
        step_rewards = self._load_step_rewards(state.steps_per_client)
        bar = _progress_bar(self.progress, plan, state)
        client_steps = [state.steps_per_client] * len(clients.names)
        client_episodes = [state.episodes.get(name, 0) for name in clients.names]

        def on_progress(index: int, info: dict[str, Any]) -> None:
            client_steps[index] = int(info["total_steps"])
            client_episodes[index] = int(info["episodes"])
            advance = min(client_steps) - bar.n
            if advance > 0:
                bar.update(advance)
            if info.get("last_return") is not None:
                state.last_returns[clients.names[index]] = float(info["last_return"])
            bar.set_postfix(
                episodes=sum(client_episodes),
                ret=_fmt(info.get("last_return")),
                round=f"{state.completed_rounds + 1}/{plan.num_rounds}",
                refresh=False,
            )

        try:
            for round_index in range(state.completed_rounds, plan.num_rounds):
                round_started = time.perf_counter()
                steps = plan.round_steps(round_index)
                start_step = state.steps_per_client

                busy_before = time.perf_counter()
                updates = clients.train(
                    steps,
                    upload=plan.aggregates,
                    include_targets=plan.targets == "average",
                    on_progress=on_progress if self.progress else None,
                )
                state.local_training_s += time.perf_counter() - busy_before
                state.dropped_clients.update(clients.dropped)
                state.client_cpu_s += sum(u.cpu_time_s for u in updates)
                state.client_training_s += max((u.wall_time_s for u in updates), default=0.0)

                bytes_up = bytes_down = 0
                if plan.aggregates:
                    began = time.perf_counter()
                    uploads = [u.parameters for u in updates]
                    if any(p is None for p in uploads):
                        raise RuntimeError("a client sent no parameters in an aggregation round")
                    weights = [u.num_steps for u in updates] if plan.weighting == "steps" else None
                    global_model = fedavg(uploads, weights)  # type: ignore[arg-type]
                    state.aggregation_s += time.perf_counter() - began
                    began = time.perf_counter()
                    clients.set_parameters(global_model, sync_targets=plan.targets == "resync")
                    state.communication_s += time.perf_counter() - began
                    state.bytes_per_upload = state_nbytes(uploads[0])  # type: ignore[arg-type]
                    state.bytes_per_download = state_nbytes(global_model)
                    bytes_up = sum(state_nbytes(p) for p in uploads)  # type: ignore[arg-type]
                    bytes_down = state.bytes_per_download * len(updates)
                    state.uploads += len(updates)
                    state.downloads += len(updates)
                    state.total_bytes_up += bytes_up
                    state.total_bytes_down += bytes_down

                state.completed_rounds = round_index + 1
                state.steps_per_client = start_step + steps
                for update in updates:
                    name = update.client
                    state.episodes[name] = state.episodes.get(name, 0) + len(update.episodes)
                    state.collisions[name] = state.collisions.get(name, 0) + sum(
                        e.collision for e in update.episodes
                    )
                    state.arrivals[name] = state.arrivals.get(name, 0) + sum(
                        e.arrived for e in update.episodes
                    )
                    if update.episodes:
                        state.last_returns[name] = update.episodes[-1].episode_return
                step_rewards = np.concatenate(
                    [step_rewards, np.mean(np.stack([u.step_rewards for u in updates]), axis=0)]
                ).astype(np.float32)

                round_time = time.perf_counter() - round_started
                began = time.perf_counter()
                if self.logger is not None:
                    self.logger.log_round(
                        start_step,
                        updates,
                        state.completed_rounds,
                        bytes_up,
                        bytes_down,
                        state.total_bytes_up + state.total_bytes_down,
                        round_time,
                    )
                    self.logger.flush()
                state.logging_s += time.perf_counter() - began

                began = time.perf_counter()
                self._checkpoint(state, step_rewards)
                state.checkpoint_s += time.perf_counter() - began
                state.round_times_s.append(time.perf_counter() - round_started)
                state.wall_time_s += time.perf_counter() - round_started
                # Commit again so the timing of this round's checkpoint is kept too.
                write_json_atomic(self.run_dir / STATE_FILE, state.to_dict())
                if bar.n < state.steps_per_client:
                    bar.update(state.steps_per_client - bar.n)
                bar.set_postfix(
                    episodes=sum(state.episodes.values()),
                    ret=_fmt(_mean(state.last_returns.values())),
                    round=f"{state.completed_rounds}/{plan.num_rounds}",
                )
                if self.on_round_end is not None:
                    self.on_round_end(state)

            if not state.training_finished:
                self._save_models()
                state.training_finished = True
                checkpoint, state.checkpoint = state.checkpoint, None
                write_json_atomic(self.run_dir / STATE_FILE, state.to_dict())
                # The models are saved; the replay buffers are not needed any more.
                if checkpoint is not None:
                    shutil.rmtree(self.run_dir / checkpoint, ignore_errors=True)
        finally:
            bar.close()
        return state

    # ------------------------------------------------------------------ files
    def _load_step_rewards(self, steps: int) -> np.ndarray:
        path = self.run_dir / STEP_REWARDS_FILE
        if steps == 0 or not path.exists():
            return np.zeros(0, np.float32)
        # A killed session may have written past its last commit: keep the committed part.
        return np.load(path)[:steps].astype(np.float32)

    def _checkpoint(self, state: RunState, step_rewards: np.ndarray) -> None:
        """Write the round's client states, then commit it in ``state.json``."""
        relative = Path(CHECKPOINT_DIR) / f"round_{state.completed_rounds:04d}"
        directory = self.run_dir / relative
        if directory.exists():  # left by a session killed before it committed this round
            shutil.rmtree(directory)
        self.clients.save(directory)
        state.dropped_clients.update(self.clients.dropped)  # a client may fail while saving
        _save_npy_atomic(self.run_dir / STEP_REWARDS_FILE, step_rewards)
        state.checkpoint = relative.as_posix()
        write_json_atomic(self.run_dir / STATE_FILE, state.to_dict())
        for old in (self.run_dir / CHECKPOINT_DIR).glob("round_*"):
            if old.name != directory.name:
                shutil.rmtree(old, ignore_errors=True)

    def _save_models(self) -> None:
        """Final models under ``models/`` and ``models/index.json`` (task -> file)."""
        models = self.run_dir / MODELS_DIR
        names = self.clients.names
        if self.plan.scheme == "fedavg":  # every client holds the global model
            paths: list[Path | None] = [models / "global.pt"] + [None] * (len(names) - 1)
        elif self.plan.scheme == "central":
            paths = [models / "central.pt"]
        else:
            paths = [models / f"{name}.pt" for name in names]
        self.clients.save_models(paths)
        write_json_atomic(models / MODEL_INDEX_FILE, self.plan.model_files(list(names)))


def _save_npy_atomic(path: Path, array: np.ndarray) -> None:
    import io

    buffer = io.BytesIO()
    np.save(buffer, array)
    write_bytes_atomic(path, buffer.getvalue())


def _mean(values: Any) -> float | None:
    values = list(values)
    return float(np.mean(values)) if values else None


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _progress_bar(enabled: bool, plan: FederationPlan, state: RunState) -> Any:
    from tqdm.auto import tqdm

    return tqdm(
        total=plan.total_steps,
        initial=state.steps_per_client,
        unit="step",
        desc=f"{plan.scheme} ({len(plan.client_tasks)} client{'s' * (len(plan.client_tasks) > 1)})",
        disable=not enabled,
        dynamic_ncols=True,
        mininterval=0.5,
    )
