"""A training run from a composed config to its ``results.json``: :func:`train`.

The run directory's layout, state and resume lookup belong to :mod:`frl.run_directory`,
the versions recorded with a run to :mod:`frl.provenance`; ``python -m frl.train`` is the
Hydra entry point over :func:`train`. docs/training.md describes the TensorBoard tags and
the keys of ``results.json``.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from frl import run_directory as rundir
from frl.agents.config import DDPGConfig
from frl.agents.precision import precision_report
from frl.envs.config import traffic_name
from frl.federation.assembly import client_specs, round_tester, worker_processes, worker_threads
from frl.federation.client_pool import ProcessClientPool
from frl.federation.collision_budget import budget_end_state, budget_lines
from frl.federation.coordinator import run_logged
from frl.federation.plan import FederationPlan
from frl.federation.strategies import ServerStrategy
from frl.federation.tensorboard import (
    EPISODE_WINDOW,
    TrainingLogger,
    mean_over_clients,
)
from frl.federation.workers import ClientFailure
from frl.fileio import read_json, write_json_atomic
from frl.provenance import versions
from frl.run_directory import RoundHook, RunState
from frl.run_opening import config_value, open_run
from frl.train_config import TrainSettings
from frl.update_count import updates_due

log = logging.getLogger("frl.train")

ROUND_TEST_SEEDS_DEFINITION = (
    "odd SUMO seeds from SeedSequence(seed, spawn_key=(0x7E57, task)), none of the final "
    "test's; the same every round"
)
FINAL_REWARD_FRACTION = 0.1
"""``final_step_reward`` averages ``train/step_reward`` over this last share of the run."""


def schedule_line(plan: FederationPlan, agent: DDPGConfig) -> str:
    """What a run trains, in one line: its vehicles, each one's environment steps and
    updates, and its rounds of ``interval`` updates, the first one's warm-up stated. Updates
    are counted as due (every ``train_freq``-th step from ``learning_starts`` on); the first
    waits until the buffer holds a batch."""
    freq, starts = agent.train_freq, agent.learning_starts
    first_round_end = plan.round_end_step(0)
    updates = updates_due(plan.total_steps, freq, starts)
    first_round = updates_due(first_round_end, freq, starts)
    every = "an update every step" if freq == 1 else f"an update every {freq} steps"
    vehicles = plan.fleet_size
    # A fleet names its distinct tasks once, not each of its vehicles.
    tasks = ", ".join(plan.client_tasks if vehicles <= 6 else plan.test_tasks)
    rounds = "models averaged" if plan.aggregates else "checkpoints"
    return (
        f"{plan.scheme}, {vehicles} vehicle{'s' if vehicles > 1 else ''} ({tasks}): "
        f"{plan.num_rounds} rounds of {plan.interval // freq:,} updates per vehicle "
        f"({plan.interval:,} environment steps; {rounds} after each), "
        f"{plan.total_steps:,} environment steps and {updates:,} updates per vehicle, {every}; "
        f"none in the first {starts:,} steps (the warm-up), so the first round has "
        f"{first_round:,}"
    )


def train(
    cfg: DictConfig | dict[str, Any], on_round_end: RoundHook | None = None
) -> dict[str, Any]:
    """Train, checkpoint, test and write ``results.json``; return the results, with the
    run directory (``run_dir``) beside them.

    Args:
        cfg: a config composed from ``frl/conf`` (or any mapping of the schema's keys).
            ``run_dir`` defaults to Hydra's output directory.
        on_round_end: called with the :class:`RunState` after each committed round.

    Raises:
        ConfigError: invalid configuration, or no run directory to use, before any
            process starts.
        frl.federation.ClientFailure: a client's worker raised, died or timed out; its
            ``run_dir`` and ``completed_rounds`` say what ``resume=`` continues from.
    """
    job_started = time.perf_counter()
    opened = open_run(cfg, _hydra_output_dir())
    run_dir, resuming = opened.run_dir, opened.status == "resume"
    if opened.status == "finished":
        log.info("skipping %s: the run there has finished (resume=auto)", run_dir)
        return {**read_json(run_dir / rundir.RESULTS_FILE), "run_dir": os.fspath(run_dir)}
    settings, to_save = opened.settings, opened.config
    assert settings is not None and to_save is not None
    if resuming:
        log.info("resuming %s", run_dir)
    progress = bool(config_value(cfg, "progress", True)) and not _is_multirun()
    precision = precision_report(settings.agent.precision, settings.device)
    log.info(
        "agent precision: %s (agent.precision=%s; native bf16 on this %s: %s)",
        precision["used"],
        precision["configured"],
        settings.device,
        "yes" if precision["native_bf16"] else "no",
    )
    log.info("training: %s", schedule_line(settings.plan, settings.agent))
    if settings.collision_budget_by_task is not None:
        log.info(
            "collision budget by task: %s collisions per training episode (a cost critic and "
            "a Lagrange multiplier per vehicle; agent.collision_budget_by_task)",
            ", ".join(f"{task} {b:g}" for task, b in settings.collision_budget_by_task.items()),
        )
    elif settings.agent.collision_budget is not None:
        log.info(
            "collision budget: %g collisions per training episode per vehicle (a cost critic "
            "and a Lagrange multiplier per vehicle; agent.collision_budget=null: none)",
            settings.agent.collision_budget,
        )

    run_dir.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(OmegaConf.create(to_save), run_dir / rundir.CONFIG_FILE)
    run_versions = versions()
    write_json_atomic(run_dir / rundir.VERSIONS_FILE, run_versions)

    state = (rundir.read_state(run_dir) if resuming else None) or RunState()
    if not state.training_finished:
        try:
            state = train_rounds(settings, run_dir, state, progress, on_round_end)
        except ClientFailure as failure:
            failure.run_dir = run_dir
            failure.completed_rounds = (rundir.read_state(run_dir) or RunState()).completed_rounds
            raise

    results = training_results(settings, state, run_dir, run_versions)
    for line in budget_lines(results["training"]["collision_budget"] or {}):
        log.info("collision budget, %s", line)
    previous = rundir.read_results(run_dir)
    if previous is not None and "evaluation" in previous:  # keep an earlier evaluation
        results["evaluation"] = previous["evaluation"]
    rundir.write_results(run_dir, results)

    if settings.eval_episodes > 0:
        from frl.evaluate import evaluate_run

        began = time.perf_counter()
        results["evaluation"] = evaluate_run(run_dir, progress=progress, verbose=True)
        results["evaluation_wall_time_s"] = time.perf_counter() - began
    if results["round_tests"] is not None and settings.yardsticks:
        from frl.evaluate import evaluate_round_test_yardsticks

        # The curve's reference, on its own seeds: each round pairs with the rule.
        began = time.perf_counter()
        results["round_tests"]["yardsticks"] = evaluate_round_test_yardsticks(
            run_dir, progress=progress, verbose=False
        )
        results["round_tests"]["yardsticks_wall_time_s"] = time.perf_counter() - began
    results["job_wall_time_s"] = time.perf_counter() - job_started
    rundir.write_results(run_dir, results)
    _log_hparams(run_dir, settings, results)
    log.info("run directory: %s", run_dir)
    return {**results, "run_dir": os.fspath(run_dir)}


def train_rounds(
    settings: TrainSettings,
    run_dir: Path,
    state: RunState,
    progress: bool = False,
    on_round_end: RoundHook | None = None,
) -> RunState:
    """The round loop on ``federation.backend``, from ``state`` to the end; the final state.

    Under ``flower`` with the deployment runtime the rounds run in the ServerApp's
    process, so ``on_round_end`` is not called there.
    """
    specs = client_specs(settings)
    if settings.backend == "flower":
        from frl.flower.launch import train_rounds as flower_rounds

        return flower_rounds(settings, specs, run_dir, state, progress, on_round_end)
    workers = worker_processes(settings)
    with ProcessClientPool(
        specs,
        num_threads=worker_threads(settings, workers),
        timeout_s=settings.worker_timeout_s,
        state_dir=run_dir,
        num_workers=workers,
        stack_updates=settings.stack_updates,
    ) as pool:
        return run_logged(
            settings.plan,
            pool,
            run_dir,
            state,
            ServerStrategy(settings.strategy),
            settings.seed,
            progress,
            on_round_end,
            round_tester(settings),
        )


def traffic_label(scenario: Any) -> str:
    """A vehicle's traffic in results.json: its preset, with its arrival period."""
    return (
        f"{traffic_name(scenario)} (arrival period {scenario.human_arrival_period_steps:g} steps)"
    )


def final_episode_return_mean(state: RunState) -> float | None:
    """``rollout/ep_rew_mean`` at the run's end; None until every client ended an episode
    (or for a run whose state predates the windows)."""
    windows = [state.recent_returns.get(name) for name in state.episodes]
    if not windows or not all(windows):
        return None
    return mean_over_clients(windows)


def round_tests_section(settings: TrainSettings, state: RunState) -> dict[str, Any] | None:
    """The per-round test curve of ``results.json``; None for a run without it."""
    if not state.round_tests:
        return None
    return {
        "episodes_per_task": settings.round_test_episodes,
        "exploration": False,
        "seeds": ROUND_TEST_SEEDS_DEFINITION,
        "points": state.round_tests,
    }


def collision_budget_state(settings: TrainSettings, state: RunState) -> dict[str, Any] | None:
    """Each vehicle's collision budget at the end of training (None without a budget):
    its last round's training collision rate, whether that kept the budget, and whether
    its multiplier levelled off (:func:`frl.federation.collision_budget.budget_end_state`)."""
    if settings.agent.collision_budget is None:
        return None
    return {
        spec.name: budget_end_state(state.budget_rounds[spec.name], spec.agent.collision_budget)
        for spec in client_specs(settings)
        if state.budget_rounds.get(spec.name) and spec.agent.collision_budget is not None
    }


def training_results(
    settings: TrainSettings, state: RunState, run_dir: Path, run_versions: Mapping[str, Any]
) -> dict[str, Any]:
    """The training and communication sections of ``results.json``; ``run_versions`` are
    the versions this session trained with (``versions.json``)."""
    plan = settings.plan
    step_rewards = rundir.read_step_rewards(run_dir)
    tail = max(1, int(len(step_rewards) * FINAL_REWARD_FRACTION))
    wall = state.wall_time_s
    return {
        "scheme": plan.scheme,
        "backend": settings.backend,
        "seed": settings.seed,
        "interval": plan.interval,
        "interval_updates": plan.interval // settings.agent.train_freq,
        "total_steps": plan.total_steps,
        "tasks": list(plan.test_tasks),
        "clients": [spec.name for spec in client_specs(settings)],
        "fleet": {
            "vehicles": plan.fleet_size,
            "vehicle_tasks": list(plan.client_tasks),
            "vehicles_per_round": plan.vehicles_drawn,
            "strategy": settings.strategy.name if plan.aggregates else None,
            "strategy_params": dict(settings.strategy.params) if plan.aggregates else None,
            "vehicle_traffic": (
                None
                if settings.vehicle_envs is None
                else [traffic_label(env.scenario) for env in settings.vehicle_envs]
            ),
            "vehicle_steps": {
                spec.name: state.vehicle_steps.get(spec.name, 0) for spec in client_specs(settings)
            },
            "participants": state.participants or None,
        },
        "rounds": state.completed_rounds,
        # Resolved on the machine that wrote this file; workers on it resolve alike.
        "agent_precision": precision_report(settings.agent.precision, settings.device),
        "communication": {
            "aggregation": plan.aggregates,
            "targets": plan.targets if plan.aggregates else None,
            "bytes_per_upload": state.bytes_per_upload,
            "bytes_per_download": state.bytes_per_download,
            "uploads": state.uploads,
            "downloads": state.downloads,
            "total_bytes_up": state.total_bytes_up,
            "total_bytes_down": state.total_bytes_down,
            "total_bytes": state.total_bytes_up + state.total_bytes_down,
        },
        "training": {
            "steps_per_client": state.steps_per_client,
            "wall_time_s": wall,
            "seconds_per_round": wall / state.completed_rounds if state.completed_rounds else None,
            "local_training_s": state.local_training_s,
            "client_cpu_s": state.client_cpu_s,
            "client_training_s": state.client_training_s,
            "outside_training_share": (
                max(0.0, wall - state.client_training_s) / wall if wall else None
            ),
            "coordinator_overhead_s": state.coordinator_overhead_s,
            "coordinator_overhead_share": state.coordinator_overhead_s / wall if wall else None,
            "aggregation_s": state.aggregation_s,
            "communication_s": state.communication_s,
            "checkpoint_s": state.checkpoint_s,
            "logging_s": state.logging_s,
            "round_test_s": state.round_test_s,
            "round_test_share": state.round_test_s / wall if wall else None,
            "episodes": state.episodes,
            "collisions": state.collisions,
            "arrivals": state.arrivals,
            "collision_budget": collision_budget_state(settings, state),
            "dropped_clients": state.dropped_clients,
            "final_step_reward": float(step_rewards[-tail:].mean()) if len(step_rewards) else None,
            "final_step_reward_definition": (
                f"mean of train/step_reward over the last {FINAL_REWARD_FRACTION:.0%} of steps"
            ),
            "final_ep_rew_mean": final_episode_return_mean(state),
            "final_ep_rew_mean_definition": (
                f"rollout/ep_rew_mean at the end (Fig. 4's final training reward): each "
                f"client's mean return over its last {EPISODE_WINDOW} training episodes, "
                "averaged over the clients"
            ),
        },
        "round_tests": round_tests_section(settings, state),
        # Taken at the session's start: HEAD may have moved by now.
        "versions": dict(run_versions),
        "run_dir": os.fspath(run_dir),
    }


# ------------------------------------------------------------------ the config
def _is_multirun() -> bool:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def _hydra_output_dir() -> Path | None:
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        return Path(HydraConfig.get().runtime.output_dir)
    return None


def _log_hparams(run_dir: Path, settings: TrainSettings, results: dict[str, Any]) -> None:
    plan, agent = settings.plan, settings.agent
    hparams = {
        "scheme": plan.scheme,
        "interval": plan.interval // agent.train_freq,  # updates, as the config counts
        "total_steps": plan.total_steps,
        "seed": settings.seed,
        "targets": plan.targets,
        "weighting": plan.weighting,
        "initial_model": "shared" if plan.shares_initial_model else "independent",
        "reward": settings.reward.name,
        "hidden_sizes": list(agent.hidden_sizes),
        "actor_lr": agent.actor_lr,
        "critic_lr": agent.critic_lr,
        "batch_size": agent.batch_size,
        "tau": agent.tau,
        "learning_starts": agent.learning_starts,
        "noise_sigma": agent.noise.sigma,
        "precision": results["agent_precision"]["used"],
    }
    metrics = ["rollout/ep_rew_mean", "train/final_step_reward", "server/bytes_total"]
    if "evaluation" in results:
        metrics += [
            f"eval/average/{name}"
            for name in ("average_reward", "collision_rate", "average_travel_time")
        ]
    with TrainingLogger(run_dir / rundir.TB_DIR) as logger:
        final = results["training"]["final_step_reward"]
        if final is not None:
            logger.writer.add_scalar("train/final_step_reward", final, plan.total_steps)
        logger.log_hparams(hparams, metrics)
