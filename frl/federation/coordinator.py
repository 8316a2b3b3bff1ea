"""The roadside unit: drives rounds, aggregates with :func:`fedavg`, logs and checkpoints.

One round (Section III.C, Fig. 2):

1. every vehicle trains ``interval`` environment steps locally, in parallel; where rounds
   draw a part of the fleet (``fraction_train``), only the drawn vehicles, each first
   receiving the current global model, as Flower's ``configure_train`` sends it;
2. ``fedavg`` only: the vehicles upload their models, the roadside unit aggregates them
   with the run's strategy (Eq. (3) by default, :mod:`frl.federation.strategies`) and,
   where the whole fleet trains, sends the global model back to every vehicle;
3. the round is logged and checkpointed: every client's full state (agent, replay
   buffer, optimizer, noise, generators), the roadside unit's (the global model and the
   strategy's momentum or moments, where the run needs them), then ``state.json``,
   which commits the round; with a :class:`RoundTester`, the deployed model's test on
   the round-test seeds is committed with it (the per-round test curve).

A run killed at any point resumes from the last committed round with nothing before it
lost, and ends as the run never killed: each vehicle's checkpoint holds its drive
(:mod:`frl.federation.vehicle_snapshot`), so the episode running at the commit goes on.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
from torch import Tensor

from frl import run_directory as rundir
from frl.agents.checkpoint import read_checkpoint, write_checkpoint
from frl.agents.federated import is_target_key
from frl.federation.averaging import state_nbytes
from frl.federation.client import LocalUpdate
from frl.federation.client_pool import ClientPool
from frl.federation.collision_budget import round_record
from frl.federation.plan import FederationPlan, round_sample
from frl.federation.round_tests import RoundTester
from frl.federation.strategies import Aggregator, ServerStrategy, StrategySpec
from frl.federation.tensorboard import EPISODE_WINDOW, TrainingLogger, resume_purge_step
from frl.fileio import write_json_atomic
from frl.run_directory import RoundHook, RunState

log = logging.getLogger("frl.train")

ROUND_TEST_PREFIX = "eval/round"
"""TensorBoard prefix of the per-round test curve: ``eval/round/{task or average}/{metric}``."""


class Coordinator:
    """Runs the rounds of ``plan`` over ``clients``, writing into ``run_dir``.

    Args:
        plan: scheme, budget and interval.
        clients: a started :class:`ClientPool`.
        run_dir: where checkpoints, models and ``state.json`` go.
        logger: TensorBoard logger, or None.
        progress: show a progress bar over the run.
        on_round_end: called after each committed round (tests use it to simulate a kill).
        seed: the run seed, from which rounds draw their vehicles.
        strategy: the aggregation (default: FedAvg, Eq. (3)); Flower's backend passes its
            own classes behind the same ``aggregate`` / ``state_dict`` methods.
        round_tester: tests the deployed model(s) after every round (the per-round test
            curve), or None.
    """

    def __init__(
        self,
        plan: FederationPlan,
        clients: ClientPool,
        run_dir: Path,
        logger: TrainingLogger | None = None,
        progress: bool = False,
        on_round_end: RoundHook | None = None,
        seed: int = 0,
        strategy: Aggregator | None = None,
        round_tester: RoundTester | None = None,
    ) -> None:
        self.plan = plan
        self.clients = clients
        self.run_dir = Path(run_dir)
        self.logger = logger
        self.progress = progress
        self.on_round_end = on_round_end
        self.seed = seed
        self.strategy: Aggregator = strategy or ServerStrategy(StrategySpec())
        self.round_tester = round_tester
        self.global_model: dict[str, Any] | None = None
        """The roadside unit's copy of the global model, kept where a strategy steps
        from it or where vehicles left out of a round fetch it later."""

    @property
    def _keeps_global_model(self) -> bool:
        return self.plan.aggregates and (self.strategy.spec.needs_global_model or self.plan.samples)

    def run(self, state: RunState) -> RunState:
        """Train from ``state`` (fresh or loaded) to the end of the budget; return the state."""
        if state.checkpoint is not None and not state.training_finished:
            began = time.perf_counter()
            without_drive = self.clients.load(self.run_dir / state.checkpoint)
            self._load_server_state(self.run_dir / state.checkpoint)
            log.info(
                "round %d's checkpoint restored in %.1f s (agents, buffers and each "
                "vehicle's simulation replayed to where it stood)",
                state.completed_rounds,
                time.perf_counter() - began,
            )
            if without_drive:
                log.info(
                    "round %d's checkpoint was written before vehicles saved their drive "
                    "(%s): the episodes running then are dropped, so this run goes on in "
                    "new simulations and will not end as the run never stopped",
                    state.completed_rounds,
                    ", ".join(without_drive),
                )
        if (
            self.plan.aggregates
            and self.strategy.spec.needs_global_model
            and self.global_model is None
            and not state.training_finished
        ):
            # A server optimiser steps from the shared initial model, which every vehicle
            # holds before the first round.
            self.global_model = self._uploadable(self.clients.get_model(0))
        step_rewards = rundir.read_step_rewards(self.run_dir, state.steps_per_client)
        progress = _RunProgress(self.progress, self.plan, state, self.clients.names)
        try:
            for round_index in range(state.completed_rounds, self.plan.num_rounds):
                step_rewards = self._round(round_index, state, step_rewards, progress)
                if self.on_round_end is not None:
                    self.on_round_end(state)
            if not state.training_finished:
                self._finish(state)
        finally:
            progress.close()
        return state

    def _round(
        self, round_index: int, state: RunState, step_rewards: np.ndarray, progress: _RunProgress
    ) -> np.ndarray:
        """Train, aggregate, log and commit one round; the run's step rewards so far."""
        round_started = time.perf_counter()
        steps = self.plan.round_steps(round_index)
        start_step = state.steps_per_client
        drawn = self._draw(round_index)
        bytes_fetched = 0
        if drawn is not None:
            state.participants.append([self.clients.names[i] for i in drawn])
            if self.plan.aggregates and self.global_model is not None:
                # As Flower's configure_train: the drawn vehicles start from the global model.
                began = time.perf_counter()
                self.clients.set_parameters(
                    self.global_model, sync_targets=self.plan.targets == "resync", vehicles=drawn
                )
                state.communication_s += time.perf_counter() - began
                bytes_fetched = state_nbytes(self.global_model) * len(drawn)
                state.downloads += len(drawn)
                state.total_bytes_down += bytes_fetched

        began = time.perf_counter()
        updates = self.clients.train(
            steps,
            upload=self.plan.aggregates,
            include_targets=self.plan.targets == "average",
            on_progress=progress.on_client_progress if self.progress else None,
            vehicles=drawn,
        )
        state.local_training_s += time.perf_counter() - began
        state.dropped_clients.update(self.clients.dropped)
        state.client_cpu_s += sum(u.cpu_time_s for u in updates)
        state.client_training_s += max((u.wall_time_s for u in updates), default=0.0)

        for update in updates:
            state.vehicle_steps[update.client] = update.total_steps
        bytes_up, bytes_down = (
            self._aggregate(updates, state, round_index + 1, broadcast=drawn is None)
            if self.plan.aggregates
            else (0, 0)
        )
        bytes_down += bytes_fetched
        state.completed_rounds = round_index + 1
        state.steps_per_client = start_step + steps
        returns_before = {name: list(window) for name, window in state.recent_returns.items()}
        _count_episodes(state, updates)
        step_rewards = np.concatenate(
            [step_rewards, np.mean(np.stack([u.step_rewards for u in updates]), axis=0)]
        ).astype(np.float32)
        round_test = self._test_round(state)

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
                recent_returns=returns_before,
            )
            if round_test is not None:
                self.logger.log_evaluation(
                    round_test["per_task"],
                    round_test["average"],
                    state.steps_per_client,
                    prefix=ROUND_TEST_PREFIX,
                )
            self.logger.flush()
        state.logging_s += time.perf_counter() - began

        began = time.perf_counter()
        self._checkpoint(state, step_rewards)
        state.checkpoint_s += time.perf_counter() - began
        state.round_times_s.append(time.perf_counter() - round_started)
        state.wall_time_s += time.perf_counter() - round_started
        # Commit again so the timing of this round's checkpoint is kept too.
        rundir.write_state(self.run_dir, state)
        progress.round_committed(state)
        return step_rewards

    def _test_round(self, state: RunState) -> dict[str, Any] | None:
        """Test the deployed model(s) on the round-test seeds; the point added to
        ``state.round_tests``, or None without a round tester."""
        if self.round_tester is None:
            return None
        began = time.perf_counter()
        point = {"step": state.steps_per_client, **self.round_tester.test(self._deployed())}
        state.round_tests.append(point)
        state.round_test_s += time.perf_counter() - began
        return point

    def _deployed(self) -> dict[str, list[dict[str, Tensor]]]:
        """Each test task's model(s), as the final test deploys them (``plan.model_files``):
        the global model (FedAvg), the one model (Central), the task's vehicles (Sep)."""
        tasks = self.plan.test_tasks
        if self.plan.scheme == "separate":
            return {
                task: [
                    self.clients.get_model(index)
                    for index, vehicle_task in enumerate(self.plan.client_tasks)
                    if vehicle_task == task
                ]
                for task in tasks
            }
        # Under fraction_train the roadside unit holds the global model; otherwise
        # every vehicle does, the first included.
        model = self.global_model if self.global_model is not None else self.clients.get_model(0)
        return {task: [model] for task in tasks}

    def _draw(self, round_index: int) -> list[int] | None:
        """The vehicles (indices into ``clients.names``) that train this round; None: all."""
        if not self.plan.samples:
            return None
        live = range(len(self.clients.names))  # a dropped vehicle is drawn no more
        return round_sample(self.seed, round_index, live, self.plan.vehicles_drawn)

    def _aggregate(
        self, updates: list[LocalUpdate], state: RunState, server_round: int, broadcast: bool
    ) -> tuple[int, int]:
        """Aggregate the uploads with the strategy and, with ``broadcast``, send the global
        model down to every vehicle; the round's bytes up and down."""
        began = time.perf_counter()
        uploads = [u.parameters for u in updates]
        if any(p is None for p in uploads):
            raise RuntimeError("a client sent no parameters in an aggregation round")
        weights = [u.num_steps for u in updates] if self.plan.weighting == "steps" else None
        global_model = self.strategy.aggregate(
            uploads,  # type: ignore[arg-type]
            weights,
            self.global_model,
            server_round,
        )
        if self._keeps_global_model:
            self.global_model = global_model
        state.aggregation_s += time.perf_counter() - began
        state.bytes_per_upload = state_nbytes(uploads[0])  # type: ignore[arg-type]
        state.bytes_per_download = state_nbytes(global_model)
        bytes_up = sum(state_nbytes(p) for p in uploads)  # type: ignore[arg-type]
        state.uploads += len(updates)
        state.total_bytes_up += bytes_up
        if not broadcast:
            return bytes_up, 0
        began = time.perf_counter()
        self.clients.set_parameters(global_model, sync_targets=self.plan.targets == "resync")
        state.communication_s += time.perf_counter() - began
        bytes_down = state.bytes_per_download * len(self.clients.names)
        state.downloads += len(self.clients.names)
        state.total_bytes_down += bytes_down
        return bytes_up, bytes_down

    def _uploadable(self, model: dict[str, Any]) -> dict[str, Any]:
        """``model`` as the vehicles upload it (without targets under ``targets=resync``)."""
        if self.plan.targets == "average":
            return model
        return {key: value for key, value in model.items() if not is_target_key(key)}

    def _finish(self, state: RunState) -> None:
        """Save the final models, mark training finished and drop the last checkpoint."""
        if self.plan.aggregates and self.plan.samples and self.global_model is not None:
            # The first vehicle may have sat out the last round: it writes the global model.
            self.clients.set_parameters(
                self.global_model, sync_targets=self.plan.targets == "resync", vehicles=[0]
            )
        self._save_models()
        state.training_finished = True
        checkpoint, state.checkpoint = state.checkpoint, None
        rundir.write_state(self.run_dir, state)
        # The models are saved; the replay buffers are not needed any more.
        if checkpoint is not None:
            shutil.rmtree(self.run_dir / checkpoint, ignore_errors=True)

    # ------------------------------------------------------------------ files
    def _checkpoint(self, state: RunState, step_rewards: np.ndarray) -> None:
        """Write the round's client states, then commit it in ``state.json``."""
        relative = rundir.checkpoint_dir(state.completed_rounds)
        directory = self.run_dir / relative
        if directory.exists():  # left by a session killed before it committed this round
            shutil.rmtree(directory)
        self.clients.save(directory)
        self._save_server_state(directory)
        state.dropped_clients.update(self.clients.dropped)  # a client may fail while saving
        rundir.write_step_rewards(self.run_dir, step_rewards)
        state.checkpoint = relative
        rundir.write_state(self.run_dir, state)
        for old in directory.parent.glob("round_*"):
            if old.name != directory.name:
                shutil.rmtree(old, ignore_errors=True)

    def _save_server_state(self, directory: Path) -> None:
        """The global model and the strategy's state, where resuming needs them."""
        if not self._keeps_global_model or self.global_model is None:
            return
        write_checkpoint(
            {"global_model": self.global_model, "strategy": self.strategy.state_dict()},
            directory / rundir.SERVER_STATE_FILE,
        )

    def _load_server_state(self, directory: Path) -> None:
        path = directory / rundir.SERVER_STATE_FILE
        if not self._keeps_global_model or not path.exists():
            return
        data = read_checkpoint(path)
        self.global_model = dict(data["global_model"])
        self.strategy.load_state_dict(dict(data["strategy"]))

    def _save_models(self) -> None:
        """Final models under ``models/`` and ``models/index.json`` (task -> file)."""
        models = self.run_dir / rundir.MODELS_DIR
        names = self.clients.names
        if self.plan.scheme == "fedavg":  # every client holds the global model
            paths: list[Path | None] = [models / "global.pt"] + [None] * (len(names) - 1)
        elif self.plan.scheme == "central":
            paths = [models / "central.pt"]
        else:
            paths = [models / f"{name}.pt" for name in names]
        self.clients.save_models(paths)
        write_json_atomic(models / rundir.MODEL_INDEX_FILE, self.plan.model_files(list(names)))


def run_logged(
    plan: FederationPlan,
    clients: ClientPool,
    run_dir: Path,
    state: RunState,
    strategy: Aggregator,
    seed: int,
    progress: bool = False,
    on_round_end: RoundHook | None = None,
    round_tester: RoundTester | None = None,
) -> RunState:
    """The rounds from ``state`` to the end, logged to the run's TensorBoard directory
    (a resumed run's events past its last commit dropped); whatever carries the messages.
    ``round_tester``, if any, is started here and stopped at the end."""
    tb_dir = run_dir / rundir.TB_DIR
    with (
        TrainingLogger(
            tb_dir,
            purge_step=resume_purge_step(tb_dir, state.steps_per_client),
            tasks=plan.client_tasks,
        ) as logger,
        round_tester or contextlib.nullcontext(),
    ):
        coordinator = Coordinator(
            plan,
            clients,
            run_dir,
            logger,
            progress,
            on_round_end,
            seed=seed,
            strategy=strategy,
            round_tester=round_tester,
        )
        return coordinator.run(state)


def _count_episodes(state: RunState, updates: list[LocalUpdate]) -> None:
    for update in updates:
        name = update.client
        state.episodes[name] = state.episodes.get(name, 0) + len(update.episodes)
        state.collisions[name] = state.collisions.get(name, 0) + sum(
            e.collision for e in update.episodes
        )
        state.arrivals[name] = state.arrivals.get(name, 0) + sum(e.arrived for e in update.episodes)
        state.budget_rounds.setdefault(name, []).append(
            round_record(
                update.episodes,
                update.losses.get("lagrange_multiplier"),
                update.losses.get("collision_rate"),
            )
        )
        if update.episodes:
            state.last_returns[name] = update.episodes[-1].episode_return
            window = state.recent_returns.get(name, []) + [
                e.episode_return for e in update.episodes
            ]
            state.recent_returns[name] = window[-EPISODE_WINDOW:]


class _RunProgress:
    """The progress bar over a run's steps, fed by the clients' reports and the commits."""

    def __init__(
        self, enabled: bool, plan: FederationPlan, state: RunState, names: list[str]
    ) -> None:
        from tqdm.auto import tqdm

        clients = len(plan.client_tasks)
        self.plan, self.state, self.names = plan, state, names
        self.bar = tqdm(
            total=plan.total_steps,
            initial=state.steps_per_client,
            unit="step",
            desc=f"{plan.scheme} ({clients} client{'s' * (clients > 1)})",
            disable=not enabled,
            dynamic_ncols=True,
            mininterval=0.5,
        )
        self.client_steps = [state.steps_per_client] * len(names)
        self.client_episodes = [state.episodes.get(name, 0) for name in names]

    def on_client_progress(self, index: int, info: dict[str, Any]) -> None:
        """A client's report during local training (``on_progress`` of a ClientPool)."""
        self.client_steps[index] = int(info["total_steps"])
        self.client_episodes[index] = int(info["episodes"])
        advance = min(self.client_steps) - self.bar.n
        if advance > 0:
            self.bar.update(advance)
        if info.get("last_return") is not None:
            self.state.last_returns[self.names[index]] = float(info["last_return"])
        self.bar.set_postfix(
            episodes=sum(self.client_episodes),
            ret=_fmt(info.get("last_return")),
            round=f"{self.state.completed_rounds + 1}/{self.plan.num_rounds}",
            refresh=False,
        )

    def round_committed(self, state: RunState) -> None:
        if self.bar.n < state.steps_per_client:
            self.bar.update(state.steps_per_client - self.bar.n)
        self.bar.set_postfix(
            episodes=sum(state.episodes.values()),
            ret=_fmt(_mean(state.last_returns.values())),
            round=f"{state.completed_rounds}/{self.plan.num_rounds}",
        )

    def close(self) -> None:
        self.bar.close()


def _mean(values: Any) -> float | None:
    values = list(values)
    return float(np.mean(values)) if values else None


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"
