"""``python -m frl.train``: the Hydra entry point of a training run.

    python -m frl.train                          # FedAvg-DDPG, 80,000 steps, an update every 8
    python -m frl.train budget=paper             # the paper's 10,000 steps, an update each
    python -m frl.train -m federation=central,separate,fedavg seed=0,1,2
    python -m frl.train +experiment=quick                 # about a minute
    python -m frl.train resume=true                       # continue the newest killed run
    python -m frl.train -m +experiment=fig4               # resume=auto: skip finished jobs

The configs are package data (``frl/conf``, found as ``pkg://frl.conf``), so an installed
wheel trains as a checkout does. The work is :func:`frl.training.train`, re-exported
here. A user's mistake (an override that does not compose, a value :func:`validate`
refuses, a run directory that holds no run) ends the command with one line on stderr
and exit code 2, before anything runs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import sys
import traceback
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig

from frl.agents.config import GROUPS, flat_key_message
from frl.agents.retired import RETIRED_OPTIONS, without_retired_critic
from frl.federation.workers import ClientFailure
from frl.retirement import RetiredOptionError, without_retired
from frl.run_directory import RunDirectoryError, check_can_make, names_a_run
from frl.run_opening import open_run
from frl.train_config import (
    RETIRED_OUTSIDE_AGENT,
    ConfigError,
    one_line_error,
    register_configs,
    validate,
)
from frl.training import train

__all__ = ["main", "train"]

log = logging.getLogger("frl.train")  # also when run as __main__

CONFIG_MODULE = "frl.conf"
CONFIG_SEARCH_PATH = f"pkg://{CONFIG_MODULE}"
_MULTIRUN_FLAGS = ("-m", "--multirun")


def main() -> None:
    """Compose the config from the command line, train, and exit."""
    import hydra

    register_configs()
    try:
        sys.argv[1:] = without_retired_overrides(sys.argv[1:])
    except RetiredOptionError as error:
        print(f"frl.train: config error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    problem = moved_key_error(sys.argv[1:]) or override_error(sys.argv[1:])
    if problem is not None:
        print(f"frl.train: config error: {problem}", file=sys.stderr)
        raise SystemExit(2)

    @hydra.main(version_base="1.3", config_path=CONFIG_SEARCH_PATH, config_name="config")
    def hydra_main(cfg: DictConfig) -> float | None:
        import torch

        torch.set_num_threads(1)  # the roadside unit mostly waits; workers get the cores
        try:
            results = train(cfg)
        except ConfigError as error:
            print(f"frl.train: config error: {error}", file=sys.stderr)
            raise SystemExit(2) from None
        except ClientFailure as failure:
            print(f"frl.train: {failure_summary(failure)}", file=sys.stderr)
            raise SystemExit(1) from None
        draw_figure(results["run_dir"])
        evaluation = results.get("evaluation")
        return evaluation["average"]["average_reward"] if evaluation else None

    hydra_main()


def draw_figure(run_dir: str) -> None:
    """The run's picture, ``RUN_DIR/figure.png`` (:mod:`frl.plot`). A figure that cannot be
    drawn is a warning: the run and its results are already saved."""
    from frl.plot import draw_run_figure

    try:
        path = draw_run_figure(run_dir)
    except Exception as error:  # a picture must not fail a finished run
        log.warning("no figure for %s: %s", run_dir, one_line_error(error))
    else:
        log.info("figure: %s", path)


FAILURE_LOG = "failure.log"
"""Where a stopped run's full traceback goes, in its run directory."""


def failure_summary(failure: ClientFailure) -> str:
    """One line for a run a vehicle stopped: which vehicle, why, what is saved and the
    command that continues it; the full traceback is appended to ``RUN_DIR/failure.log``."""
    reason = failure.reason.strip().splitlines()[0] if failure.reason.strip() else "no reason"
    line = f"vehicle {failure.client} failed: {reason}"
    if failure.run_dir is None:
        return line
    log_path = failure.run_dir / FAILURE_LOG
    with contextlib.suppress(OSError), log_path.open("a") as log_file:
        log_file.write("".join(traceback.format_exception(failure)) + "\n")
    rounds = failure.completed_rounds or 0
    saved = (
        f"rounds 1-{rounds} are saved"
        if rounds > 1
        else ("round 1 is saved" if rounds == 1 else "no round was completed")
    )
    return (
        f"{line}; {saved}; continue with: python -m frl.train resume={failure.run_dir} "
        f"(traceback in {log_path})"
    )


RETIRED_BY_GROUP = {"agent": RETIRED_OPTIONS, **RETIRED_OUTSIDE_AGENT}
"""The retired options of each config group (:mod:`frl.retirement`)."""


def without_retired_overrides(argv: list[str]) -> list[str]:
    """``argv`` less the overrides that set a retired agent (``agent.critic`` included),
    env, reward or federation option to its off value (:mod:`frl.retirement`), which
    change nothing.

    Raises:
        RetiredOptionError: an override that sets one to any other value.
    """
    kept = []
    for arg in argv:
        key, equals, value = arg.lstrip("+").partition("=")
        if equals and key.startswith("agent.critic."):
            parsed_value = yaml.safe_load(value) if value else None
            critic_option = {key.removeprefix("agent.critic."): parsed_value}
            if not without_retired_critic(critic_option):  # a retired key at its off value
                continue
        group, _, name = key.partition(".")
        retired = RETIRED_BY_GROUP.get(group, {})
        head, _, member = name.partition(".")
        if not equals or head not in retired:
            kept.append(arg)
            continue
        parsed = yaml.safe_load(value) if value else None
        if member:  # one key of a retired group: its off value is that key's in the group's
            option = retired[head]
            off = option.off.get(member) if isinstance(option.off, dict) else None
            member_option = dataclasses.replace(option, off=off)
            without_retired({name: parsed}, {name: member_option}, group)
        else:
            without_retired({name: parsed}, retired, group)  # raises unless it is off
    return kept


def moved_key_error(argv: list[str]) -> str | None:
    """The one line naming the new form of an agent key that moved into a group
    (``agent.noise_sigma`` is ``agent.noise.sigma``, ``agent.noise=gaussian`` is
    ``agent.noise.kind=gaussian``); None if ``argv`` has none."""
    for arg in argv:
        key, equals, value = arg.lstrip("+").partition("=")
        group, _, name = key.partition(".")
        if not equals or group != "agent":
            continue
        if name in GROUPS and value and not value.startswith("{"):
            return f"agent.{name}={value} is now agent.{name}.kind={value}"
        moved = flat_key_message(name)
        if moved is not None:
            return moved
    return None


def override_error(argv: list[str]) -> str | None:
    """Why the overrides in ``argv`` do not compose, in one line; None if they do.

    Hydra itself would print a multi-line report. Sweeps (``seed=0,1,2``) are checked
    value by value, each composed config also by :func:`frl.train_config.validate`, so a
    bad value is refused before Hydra creates any run directory; a command line with
    Hydra's own flags (``--help``, ``--cfg``, ``--config-dir``, ...) is left to Hydra.
    A sweep sent to another launcher (``hydra/launcher=submitit_slurm``, ``ray``) runs
    its jobs elsewhere: their ``cores`` and ``device`` are checked where they run.
    """
    from hydra import compose, initialize_config_module
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    if any(arg.startswith("-") and arg not in _MULTIRUN_FLAGS for arg in argv):
        return None
    lines = [arg for arg in argv if arg not in _MULTIRUN_FLAGS]
    try:
        parsed = OverridesParser.create().parse_overrides(lines)
    except HydraException as error:
        return one_line_error(error)
    launcher = next((str(o.value()) for o in parsed if o.key_or_group == "hydra/launcher"), "basic")
    first, variants = [], []
    for override in parsed:
        if override.key_or_group.startswith("hydra."):
            if override.key_or_group in ("hydra.run.dir", "hydra.sweep.dir"):
                first.append(override.input_line)  # checked below: can it be made?
            continue
        if override.is_sweep_override():
            values = list(override.sweep_string_iterator())
            prefix = override.get_key_element()
            first.append(f"{prefix}={values[0]}")
            variants += [(len(first) - 1, f"{prefix}={value}") for value in values[1:]]
        else:
            first.append(override.input_line)
    candidates = [first, *([*first[:i], line, *first[i + 1 :]] for i, line in variants)]
    multirun = any(arg in _MULTIRUN_FLAGS for arg in argv)
    with initialize_config_module(config_module=CONFIG_MODULE, version_base="1.3"):
        for overrides in candidates:
            try:
                full = compose(config_name="config", overrides=overrides, return_hydra_config=True)
                cfg = OmegaConf.masked_copy(full, [key for key in full if key != "hydra"])
                _check_opens(cfg, full, multirun, this_machine=launcher == "basic")
                if launcher == "basic":  # a cluster's jobs make their directories there
                    hydra_dir = full.hydra.sweep.dir if multirun else full.hydra.run.dir
                    for path in (hydra_dir, None if multirun else cfg.run_dir):
                        if path is not None:
                            check_can_make(str(path))
            except (HydraException, OmegaConfBaseException) as error:
                return one_line_error(error)
            except (ConfigError, RunDirectoryError) as error:
                return str(error)
    return None


def _check_opens(cfg: Any, full: Any, multirun: bool, this_machine: bool) -> None:
    """Open the run as :func:`frl.training.train` will (:func:`frl.run_opening.open_run`),
    before Hydra makes a directory: a bad value, a resume with nothing to continue or a
    run already there is refused now. A sweep's jobs get directories of Hydra's choosing
    when ``run_dir`` is unset; their configs are validated, and an explicit
    ``resume=RUN_DIR`` checked."""
    if multirun and not cfg.run_dir and not names_a_run(cfg.resume):
        validate(cfg, this_machine=this_machine)
        return
    open_run(cfg, Path(full.hydra.run.dir), this_machine=this_machine, quiet=True)


if __name__ == "__main__":
    main()
