"""Federated training end to end: schemes, rounds, TensorBoard, checkpoints, evaluation.

    python -m frl.train                                   # FedAvg-DDPG, the paper's budget
    python -m frl.train federation=fedavg interval=2000
    python -m frl.train -m federation=central,separate,fedavg seed=0,1,2
    python -m frl.train +experiment=quick                 # about a minute
    python -m frl.train resume=true                       # continue the newest killed run
    python -m frl.train -m +experiment=fig4               # resume=auto: skip finished jobs

:func:`train` is the testable entry point (it takes a composed config); :func:`main` is
the thin Hydra wrapper. docs/training.md describes the run directory, the TensorBoard
tags and the keys of ``results.json``.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import logging
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

import frl
from frl.federation.client import ClientSpec
from frl.federation.coordinator import (
    STATE_FILE,
    STEP_REWARDS_FILE,
    Coordinator,
    RoundHook,
    RunState,
)
from frl.federation.fedavg import state_nbytes  # noqa: F401  (re-exported for users)
from frl.federation.plan import client_seeds, initial_model_seed
from frl.federation.pool import ProcessClientPool
from frl.federation.tensorboard import TrainingLogger, resume_purge_step
from frl.fileio import read_json, write_json_atomic
from frl.train_config import (
    ConfigError,
    TrainSettings,
    load_run_config,
    register_configs,
    validate,
)

log = logging.getLogger("frl.train")

CONFIG_FILE = "config.yaml"
VERSIONS_FILE = "versions.json"
RESULTS_FILE = "results.json"
TB_DIR = "tb"
FINAL_REWARD_FRACTION = 0.1
"""``final_step_reward`` averages ``train/step_reward`` over this last share of the run."""
_RESUME_ROOTS = ("outputs", "multirun")
_VOLATILE_KEYS = ("progress", "resume", "run_dir")
"""Keys that may differ between a run and its resumption."""


def build_client_specs(settings: TrainSettings) -> list[ClientSpec]:
    """One :class:`ClientSpec` per client of the scheme, seeded from the run seed."""
    tasks = settings.plan.client_tasks
    init_seed = initial_model_seed(settings.seed) if settings.plan.shares_initial_model else None
    return [
        ClientSpec(
            index=index,
            task=task,
            env=settings.env,
            reward=settings.reward,
            agent=settings.agent,
            agent_seed=agent_seed,
            env_seed=env_seed,
            device=settings.device,
            init_seed=init_seed,
        )
        for index, (task, (agent_seed, env_seed)) in enumerate(
            zip(tasks, client_seeds(settings.seed, len(tasks)), strict=True)
        )
    ]


def train(cfg: DictConfig, on_round_end: RoundHook | None = None) -> dict[str, Any]:
    """Train, checkpoint, test and write ``results.json``; return the results.

    Args:
        cfg: a config composed from ``conf/`` (or any mapping of the schema's keys).
            ``run_dir`` defaults to Hydra's output directory.
        on_round_end: called with the :class:`RunState` after each committed round.

    Raises:
        ConfigError: invalid configuration, before any process starts.
        frl.federation.ClientFailure: a client's worker raised, died or timed out.
    """
    job_started = time.perf_counter()
    settings = validate(cfg)
    run_dir, resuming = _resolve_run_dir(cfg)
    if resuming and _is_auto(cfg) and _finished(run_dir):
        log.info("skipping %s: the run there has finished (resume=auto)", run_dir)
        return read_json(run_dir / RESULTS_FILE)
    if resuming:
        saved = load_run_config(run_dir)
        _warn_about_changes(saved, cfg)
        settings = validate(saved)
        resolved = saved
        log.info("resuming %s", run_dir)
    else:
        resolved = cfg
    progress = bool(_get(cfg, "progress", True)) and not _is_multirun()

    run_dir.mkdir(parents=True, exist_ok=True)
    to_save = (
        OmegaConf.to_container(resolved, resolve=True)
        if isinstance(resolved, DictConfig)
        else dict(resolved)
    )
    to_save = {**to_save, "run_dir": os.fspath(run_dir), "resume": False}  # type: ignore[dict-item]
    OmegaConf.save(OmegaConf.create(to_save), run_dir / CONFIG_FILE)
    write_json_atomic(run_dir / VERSIONS_FILE, versions())

    state_path = run_dir / STATE_FILE
    state = (
        RunState.from_dict(read_json(state_path))
        if resuming and state_path.exists()
        else RunState()
    )
    if not state.training_finished:
        state = train_rounds(settings, run_dir, state, progress, on_round_end)

    results = training_results(settings, state, run_dir)
    results_path = run_dir / RESULTS_FILE
    if results_path.exists():  # keep an earlier evaluation of this run, if any
        previous = read_json(results_path)
        if "evaluation" in previous:
            results["evaluation"] = previous["evaluation"]
    write_json_atomic(results_path, results)

    if settings.eval_episodes > 0:
        from frl.evaluate import evaluate_run

        began = time.perf_counter()
        results["evaluation"] = evaluate_run(run_dir, progress=progress, verbose=True)
        results["evaluation_wall_time_s"] = time.perf_counter() - began
    results["job_wall_time_s"] = time.perf_counter() - job_started
    write_json_atomic(results_path, results)
    _log_hparams(run_dir, settings, results)
    log.info("run directory: %s", run_dir)
    return results


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
    specs = build_client_specs(settings)
    if settings.backend == "flower":
        from frl.flower.runtime import train_rounds as flower_rounds

        return flower_rounds(settings, specs, run_dir, state, progress, on_round_end)
    with (
        TrainingLogger(
            run_dir / TB_DIR, purge_step=resume_purge_step(run_dir / TB_DIR, state.steps_per_client)
        ) as logger,
        ProcessClientPool(
            specs,
            num_threads=settings.threads_per_worker,
            timeout_s=settings.worker_timeout_s,
        ) as pool,
    ):
        return Coordinator(settings.plan, pool, run_dir, logger, progress, on_round_end).run(state)


def training_results(settings: TrainSettings, state: RunState, run_dir: Path) -> dict[str, Any]:
    """The training and communication sections of ``results.json``."""
    plan = settings.plan
    step_rewards = (
        np.load(run_dir / STEP_REWARDS_FILE)
        if (run_dir / STEP_REWARDS_FILE).exists()
        else np.zeros(0)
    )
    tail = max(1, int(len(step_rewards) * FINAL_REWARD_FRACTION))
    wall = state.wall_time_s
    return {
        "scheme": plan.scheme,
        "backend": settings.backend,
        "seed": settings.seed,
        "interval": plan.interval,
        "total_steps": plan.total_steps,
        "tasks": list(plan.tasks),
        "clients": [spec.name for spec in build_client_specs(settings)],
        "rounds": state.completed_rounds,
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
            "episodes": state.episodes,
            "collisions": state.collisions,
            "arrivals": state.arrivals,
            "dropped_clients": state.dropped_clients,
            "final_step_reward": float(step_rewards[-tail:].mean()) if len(step_rewards) else None,
            "final_step_reward_definition": (
                f"mean of train/step_reward over the last {FINAL_REWARD_FRACTION:.0%} of steps"
            ),
        },
        # The versions the training ran with (written at the session's start); HEAD may
        # have moved by now.
        "versions": (
            read_json(run_dir / VERSIONS_FILE) if (run_dir / VERSIONS_FILE).exists() else versions()
        ),
        "run_dir": os.fspath(run_dir),
    }


# What decides a run's behaviour, relative to the checkout's root; see git_state().
RUN_AFFECTING_PATHS = ("frl", "conf", "pyproject.toml", "constraints.txt")


def git_state(package_dir: Path) -> tuple[str | None, bool | None]:
    """The commit of the checkout that holds ``package_dir``, and whether its code differs.

    Dirty means frl/, conf/ or the install files differ from the commit, untracked files
    there included (a new module changes a run as much as an edit). Exported results and
    reports written into docs/ during a sweep do not count. ``(None, None)`` when the
    package is not the ``frl/`` of a git checkout (an installed wheel, or a venv that
    merely sits inside some other repository).
    """

    def git(*args: str) -> str | None:
        with contextlib.suppress(OSError, subprocess.SubprocessError):
            return subprocess.run(
                ["git", *args],
                cwd=package_dir,
                capture_output=True,
                text=True,
                timeout=5,
                check=True,
            ).stdout.strip()
        return None

    root = git("rev-parse", "--show-toplevel")
    if root is None or Path(root).resolve() / "frl" != package_dir.resolve():
        return None, None
    commit = git("rev-parse", "HEAD")
    changes = git("-C", root, "status", "--porcelain", "--", *RUN_AFFECTING_PATHS)
    return commit, None if commit is None or changes is None else bool(changes)


def versions() -> dict[str, Any]:
    """Package, SUMO, torch and Python versions, and the git state (see git_state)."""
    import torch

    def dist(name: str) -> str | None:
        try:
            return importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            return None

    commit, dirty = git_state(Path(frl.__file__).parent)
    return {
        "frl": frl.__version__,
        "git_commit": commit,
        "git_dirty": dirty,
        "torch": torch.__version__,
        "numpy": np.__version__,
        "sumo": dist("eclipse-sumo"),
        "libsumo": dist("libsumo"),
        "gymnasium": dist("gymnasium"),
        "hydra": dist("hydra-core"),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
    }


# ----------------------------------------------------------------- run dirs
def _get(cfg: Any, key: str, default: Any = None) -> Any:
    return cfg.get(key, default) if hasattr(cfg, "get") else getattr(cfg, key, default)


def _is_multirun() -> bool:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def _hydra_output_dir() -> Path | None:
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        return Path(HydraConfig.get().runtime.output_dir)
    return None


def _resumable(run_dir: Path) -> bool:
    state_path = run_dir / STATE_FILE
    if not state_path.exists() or not (run_dir / CONFIG_FILE).exists():
        return False
    if not read_json(state_path).get("training_finished"):
        return True
    if not load_run_config(run_dir).get("eval_episodes", 0):
        return False
    results = run_dir / RESULTS_FILE
    return not (results.exists() and "evaluation" in read_json(results))


def _is_auto(cfg: Any) -> bool:
    resume = _get(cfg, "resume", False)
    return isinstance(resume, str) and resume.lower() == "auto"


def _finished(run_dir: Path) -> bool:
    """Training and any configured evaluation of the run in ``run_dir`` are done."""
    state_path = run_dir / STATE_FILE
    return (
        state_path.exists()
        and bool(read_json(state_path).get("training_finished"))
        and (run_dir / RESULTS_FILE).exists()
        and not _resumable(run_dir)
    )


def _resolve_run_dir(cfg: Any) -> tuple[Path, bool]:
    """The directory to write into, and whether it holds a run to resume (or skip)."""
    resume = _get(cfg, "resume", False)
    configured = _get(cfg, "run_dir")
    if _is_auto(cfg):  # deterministic sweep dirs: continue, skip or start the run there
        run_dir = Path(configured) if configured else _hydra_output_dir()
        if run_dir is None:
            raise ConfigError("run_dir must be set when train() runs outside Hydra")
        return run_dir, (run_dir / STATE_FILE).exists() and (run_dir / CONFIG_FILE).exists()
    if isinstance(resume, str) and resume.lower() not in ("true", "false", "auto"):
        run_dir = Path(resume).expanduser()
        if not (run_dir / STATE_FILE).exists():
            raise ConfigError(f"resume={resume}: no checkpointed run there (no {STATE_FILE})")
        return run_dir, True
    resume = resume is True or (isinstance(resume, str) and resume.lower() == "true")
    run_dir = Path(configured) if configured else _hydra_output_dir()
    if run_dir is None:
        raise ConfigError("run_dir must be set when train() runs outside Hydra")
    if resume:
        if _resumable(run_dir):
            return run_dir, True
        candidates = [
            path.parent
            for root in _RESUME_ROOTS
            for path in Path(root).glob(f"**/{STATE_FILE}")
            if path.parent.resolve() != run_dir.resolve() and _resumable(path.parent)
        ]
        if not candidates:
            raise ConfigError(
                f"resume=true: no unfinished run under {', '.join(_RESUME_ROOTS)}/; "
                "pass resume=RUN_DIR"
            )
        newest = max(candidates, key=lambda p: (p / STATE_FILE).stat().st_mtime)
        return newest, True
    if (run_dir / STATE_FILE).exists():
        raise ConfigError(
            f"{run_dir} already holds a run; pass resume=true to continue it or another run_dir"
        )
    return run_dir, False


def _warn_about_changes(saved: DictConfig, cfg: Any) -> None:
    """Log the keys given on the command line that the saved config overrules."""
    if not isinstance(cfg, DictConfig):
        return
    old = OmegaConf.to_container(saved, resolve=True)
    new = OmegaConf.to_container(cfg, resolve=True)
    changed = [key for key in _diff(old, new) if key.split(".")[0] not in _VOLATILE_KEYS]
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():  # only what the user typed, not the defaults
        typed = [o.split("=")[0].lstrip("+~") for o in HydraConfig.get().overrides.task]
        changed = [k for k in changed if any(k == t or k.startswith(f"{t}.") for t in typed)]
    if changed:
        log.warning(
            "resuming with the run's saved config; ignoring changed keys: %s", ", ".join(changed)
        )


def _diff(old: Any, new: Any, prefix: str = "") -> list[str]:
    if isinstance(old, dict) and isinstance(new, dict):
        keys = sorted(set(old) | set(new))
        return [d for k in keys for d in _diff(old.get(k), new.get(k), f"{prefix}{k}.")]
    return [prefix.rstrip(".")] if old != new else []


def _log_hparams(run_dir: Path, settings: TrainSettings, results: dict[str, Any]) -> None:
    plan, agent = settings.plan, settings.agent
    hparams = {
        "scheme": plan.scheme,
        "interval": plan.interval,
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
        "noise_sigma": agent.noise_sigma,
    }
    metrics = ["train/final_step_reward", "server/bytes_total"]
    if "evaluation" in results:
        metrics += [
            f"eval/average/{name}"
            for name in ("average_reward", "collision_rate", "average_travel_time")
        ]
    with TrainingLogger(run_dir / TB_DIR) as logger:
        final = results["training"]["final_step_reward"]
        if final is not None:
            logger.writer.add_scalar("train/final_step_reward", final, plan.total_steps)
        logger.log_hparams(hparams, metrics)


# --------------------------------------------------------------------- Hydra
def _hydra_main() -> None:
    import hydra

    register_configs()

    @hydra.main(version_base="1.3", config_path="../conf", config_name="config")
    def main(cfg: DictConfig) -> float | None:
        import torch

        torch.set_num_threads(1)  # the roadside unit mostly waits; workers get the cores
        try:
            results = train(cfg)
        except ConfigError as error:
            raise SystemExit(f"frl.train: config error: {error}") from None
        evaluation = results.get("evaluation")
        return evaluation["average"]["average_reward"] if evaluation else None

    main()


if __name__ == "__main__":
    sys.exit(_hydra_main())
