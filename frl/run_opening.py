"""Opening a run: where it writes, whether it is new, resumed or finished, what it runs.

:func:`open_run` is the one place that decides it, for :func:`frl.training.train` and
for ``python -m frl.train``'s check before Hydra makes a directory. It writes nothing.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from omegaconf import DictConfig, OmegaConf

from frl import run_directory as rundir
from frl.run_directory import RunDirectoryError
from frl.train_config import ConfigError, TrainSettings, load_run_config, validate

log = logging.getLogger("frl.train")

VOLATILE_KEYS = ("progress", "resume", "run_dir", "cores")
"""Keys that may differ between a run and its resumption; ``cores`` is the resuming
machine's share, taken from the new config."""

RunStatus = Literal["new", "resume", "finished"]


@dataclass(frozen=True)
class OpenedRun:
    """A run ready to train (or to skip): see :func:`open_run`."""

    run_dir: Path
    status: RunStatus
    """``new``: nothing there yet; ``resume``: continue from its last committed round (or
    test it again, if training finished); ``finished``: ``resume=auto`` found it done."""
    settings: TrainSettings | None
    """The validated settings it runs with (the saved config's, when resumed); None when
    ``finished``."""
    config: dict[str, Any] | None
    """The resolved config to save as ``RUN_DIR/config.yaml``; None when ``finished``."""


def open_run(
    cfg: DictConfig | dict[str, Any],
    default_dir: Path | None,
    this_machine: bool = True,
    quiet: bool = False,
) -> OpenedRun:
    """Find the run directory of ``cfg``, decide new, resume or finished, and validate once.

    Args:
        cfg: a composed config (or any mapping of the schema's keys).
        default_dir: Hydra's output directory, used where ``run_dir`` is unset.
        this_machine: also check ``cores`` and ``device`` here (see
            :func:`frl.train_config.validate`).
        quiet: log nothing (a check before the run, which logs when it opens).

    A resumed run runs with its saved config, read as it ran
    (:func:`frl.train_config.load_run_config`); the keys given on the command line that
    it overrules are logged, and only ``cores`` is taken from ``cfg``.

    Raises:
        ConfigError: an invalid config, or no run directory to use, in one line.
    """
    resume = config_value(cfg, "resume", False)
    try:
        run_dir, resuming = rundir.resolve(resume, config_value(cfg, "run_dir"), default_dir)
    except RunDirectoryError as error:
        raise ConfigError(str(error)) from None
    if resuming and rundir.is_auto(resume) and rundir.is_finished(run_dir):
        return OpenedRun(run_dir, "finished", None, None)
    runs: Any = cfg
    if resuming:
        runs = load_run_config(run_dir)
        if not quiet:
            _log_overruled_keys(runs, cfg)
        runs.cores = config_value(cfg, "cores", 0)
    settings = validate(runs, this_machine=this_machine)
    to_save = (
        OmegaConf.to_container(runs, resolve=True) if isinstance(runs, DictConfig) else dict(runs)
    )
    config = {**to_save, "run_dir": os.fspath(run_dir), "resume": False}
    return OpenedRun(run_dir, "resume" if resuming else "new", settings, config)  # type: ignore[arg-type]


def config_value(cfg: Any, key: str, default: Any = None) -> Any:
    """``cfg[key]`` of a DictConfig, a dict or an attribute object; ``default`` if absent."""
    return cfg.get(key, default) if hasattr(cfg, "get") else getattr(cfg, key, default)


def _log_overruled_keys(saved: DictConfig, cfg: Any) -> None:
    """Log the keys given on the command line that the saved config overrules."""
    if not isinstance(cfg, DictConfig):
        return
    old = OmegaConf.to_container(saved, resolve=True)
    new = OmegaConf.to_container(cfg, resolve=True)
    changed = [key for key in _diff(old, new) if key.split(".")[0] not in VOLATILE_KEYS]
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
