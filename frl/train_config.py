"""The training configuration: Hydra schemas, their validation and the library configs.

The schemas below are registered in Hydra's ConfigStore (``train_schema``) and are the
root of ``frl/conf/config.yaml``, so a typo (``agent.lrr=1``) or a wrong type
(``interval=abc``) fails while Hydra composes the config, before anything runs.

Each default lives in one place. The ``env``, ``agent``, ``reward`` and
``federation.flower`` schemas, and the scheme keys of ``federation``, are generated from
the library dataclasses (:func:`schema_of`); only keys that configure the run itself
(``seed``, ``eval_episodes``, the federation backend, ...) are declared here.
:func:`validate` fills what a config leaves out from these schemas, checks what a schema
cannot (``interval`` within the budget, known scheme, tasks and reward, ranges) and
builds the typed library configs; it raises :class:`ConfigError` before any process
starts. Library classes never see a DictConfig.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from frl.agents import DDPGConfig
from frl.agents.config import agent_fields_as_run
from frl.envs import EnvConfig, RewardConfig
from frl.envs.config import (
    RETIRED_ENV_OPTIONS,
    RETIRED_REWARD_OPTIONS,
    REWARD_NAMES,
    TRAFFIC_PRESETS,
)
from frl.federation.client_pool import resolve_stacking
from frl.federation.plan import (
    FEDERATION_BACKENDS,
    FLOWER_RUNTIMES,
    FederationPlan,
)
from frl.federation.reachability import unreachable_reason
from frl.federation.run_settings import (
    RETIRED_FEDERATION_OPTIONS,
    FlowerSettings,
    TrainSettings,
)
from frl.federation.strategies import StrategySpec
from frl.federation.workers import available_cores
from frl.policies import DEFAULT_YARDSTICKS, YARDSTICKS, check_teacher
from frl.retirement import RetiredOption, RetiredOptionError, without_retired
from frl.run_directory import read_saved_config


class ConfigError(ValueError):
    """The configuration is invalid; raised before any worker or SUMO starts."""


# ---------------------------------------------------------------- Hydra schemas
def schema_of(
    library_class: type,
    name: str,
    exclude: tuple[str, ...] = (),
    leading: tuple[tuple[str, type, Any], ...] = (),
    trailing: tuple[tuple[str, type, Any], ...] = (),
) -> type:
    """A Hydra schema dataclass with the fields and defaults of ``library_class``.

    OmegaConf knows neither tuples nor unions other than ``X | None``, so tuples become
    lists and other unions ``Any`` (the library class checks them); nested library
    dataclasses become nested schemas. ``leading`` and ``trailing`` add
    ``(name, type, default)`` fields that only the training config has.
    """
    hints = typing.get_type_hints(library_class)
    defaults = library_class()
    specs: list[tuple[str, Any, Any]] = [_schema_field(*extra) for extra in leading]
    for library_field in dataclasses.fields(library_class):
        if library_field.name in exclude:
            continue
        value = getattr(defaults, library_field.name)
        kind = hints[library_field.name]
        if dataclasses.is_dataclass(kind):
            nested = schema_of(kind, f"{kind.__name__.removesuffix('Config')}Schema")
            specs.append((library_field.name, nested, field(default_factory=nested)))
        else:
            specs.append(_schema_field(library_field.name, _schema_type(kind), value))
    specs += [_schema_field(*extra) for extra in trailing]
    schema = dataclasses.make_dataclass(name, specs)
    # Importable by name: a config pickled into another process (a Hydra launcher's job)
    # must find this very class there, not a copy that OmegaConf would refuse to merge.
    schema.__module__ = __name__
    if globals().setdefault(name, schema) is not schema:
        raise RuntimeError(f"two Hydra schemas named {name}")
    schema.__doc__ = (
        f"The Hydra schema of :class:`{library_class.__module__}.{library_class.__name__}`."
    )
    return schema


def _schema_type(kind: Any) -> Any:
    origin = typing.get_origin(kind)
    if origin is tuple:
        return list[typing.get_args(kind)[0]]  # type: ignore[valid-type]
    if origin in (typing.Union, types.UnionType):
        members = [arg for arg in typing.get_args(kind) if arg is not type(None)]
        if len(members) == 1:
            return _schema_type(members[0]) | None
        return Any
    return kind


def _schema_field(name: str, kind: Any, value: Any) -> tuple[str, Any, Any]:
    if dataclasses.is_dataclass(value):
        return (name, kind, field(default_factory=type(value)))
    if isinstance(value, list | tuple):
        items = list(value)
        return (name, kind, field(default_factory=lambda: list(items)))
    if isinstance(value, dict):
        entries = dict(value)
        return (name, kind, field(default_factory=lambda: dict(entries)))
    return (name, kind, field(default=value))


EnvSchema = schema_of(EnvConfig, "EnvSchema", exclude=("task",))
"""``task`` is left out: the scheme decides it."""
AgentSchema = schema_of(
    DDPGConfig,
    "AgentSchema",
    leading=(("name", str, "ddpg"),),
    trailing=(("collision_budget_by_task", dict[str, float], {}),),
)
"""``name``: the algorithm (frl implements ``ddpg``); ``collision_budget_by_task``: each
task's vehicles' collision budget, in place of ``collision_budget`` (empty: the same for
every vehicle)."""
RewardSchema = schema_of(RewardConfig, "RewardSchema")
FlowerSchema = schema_of(FlowerSettings, "FlowerSchema")
FederationSchema = schema_of(
    FederationPlan,
    "FederationSchema",
    exclude=("total_steps", "interval"),  # root keys: interval=2000
    trailing=(
        ("backend", str, "processes"),
        # processes: one spawned worker process per client (one SUMO each); flower: Flower.
        ("flower", FlowerSchema, FlowerSchema()),
        ("worker_timeout_s", float, 3600.0),
        # Longest one worker call (a round of local training) may take before the run stops.
        ("threads_per_worker", int, 0),
        # Torch threads per worker; 0: the run's ``cores`` split evenly over the workers.
        ("workers", int, 0),
        # Worker processes of the processes backend; 0: one per vehicle up to
        # max(cores, 3), beyond that vehicles share them and take turns.
        ("stack_updates", Any, "auto"),
        # The vehicles a worker hosts train in lockstep and learn in one stacked update
        # (frl.agents.stacked): true, false, or auto (on a GPU, where it pays).
        ("strategy", str, "fedavg"),
        # The roadside unit's aggregation (frl.federation.strategies.STRATEGIES).
        ("strategy_params", dict[str, float], {}),
        # The strategy's parameters, e.g. {eta: 0.01}; the rest take Flower's defaults.
        ("vehicle_traffic", list[str] | None, None),
        # Per vehicle, a traffic preset (frl.envs.TRAFFIC_PRESETS); null: env.scenario.
        ("vehicle_arrival_period_steps", list[float] | None, None),
        # Per vehicle, the humans' mean arrival period; null: its traffic's.
    ),
)


CONFIG_VERSION = 2
"""The run config's format. 2 (since 2026-11-27): ``interval`` counts updates; 1 (a saved
config without the key): environment steps, read by :func:`migrate_saved_config`."""


@dataclass
class TrainSchema:
    """Root of ``frl/conf/config.yaml``. The budget is three keys, set by the ``budget``
    group: ``total_steps``, the environment steps each vehicle drives; ``agent.train_freq``,
    the environment steps per update; and ``interval``, the updates each vehicle trains
    between two uploads (the paper's "local training epochs", Section IV.B, where a step is
    an update). ``data`` (80,000 steps, an update every 8, interval 2,000: 5 rounds; the
    default) and ``paper`` (10,000 steps, an update each, interval 2,000: 5 rounds) differ
    in the data behind each update only. The defaults below are the library's (paper)."""

    seed: int = 0
    total_steps: int = FederationPlan.total_steps
    """Environment steps per vehicle."""
    interval: int = FederationPlan.interval
    """Updates per vehicle between aggregations (FedAvg) or checkpoints (all): a round is
    ``interval * agent.train_freq`` environment steps, the first one's warm-up included."""
    config_version: int = CONFIG_VERSION
    """The format of this config (:data:`CONFIG_VERSION`); saved configs without it are
    migrated."""
    eval_episodes: int = 100
    """Test episodes per task after training (Section IV.B); 0 skips evaluation. Tests
    run on the training traffic (``env.scenario``, set by the ``traffic`` group)."""
    round_test_episodes: int = 0
    """Test episodes per task after every round, on seeds of their own (the per-round test
    curve, ``eval/round/...``); 0: none."""
    yardsticks: list[str] = field(default_factory=lambda: list(DEFAULT_YARDSTICKS))
    """Yardstick policies tested on the same seeds beside the model (frl.policies)."""
    progress: bool = True
    """Progress bar; always off in multirun."""
    resume: Any = False
    """false; true (the newest unfinished run under outputs/, or run_dir); a run dir; or
    auto (the run in run_dir: continued if unfinished, skipped if finished, else started)."""
    device: str = "cpu"
    cores: int = 0
    """CPU cores the run may use: its worker processes split them evenly (torch threads,
    at least one each); 0: every core available to the process. Runs side by side each
    take their share, e.g. ``cores=1`` for two runs on two cores."""
    run_dir: Any = None
    """Where the run writes; null: Hydra's output directory."""
    env: EnvSchema = field(default_factory=EnvSchema)  # type: ignore[valid-type]
    agent: AgentSchema = field(default_factory=AgentSchema)  # type: ignore[valid-type]
    federation: FederationSchema = field(default_factory=FederationSchema)  # type: ignore[valid-type]
    reward: RewardSchema = field(default_factory=RewardSchema)  # type: ignore[valid-type]


def register_configs() -> None:
    """Put the schema and the traffic presets into Hydra's ConfigStore (idempotent).

    The ``traffic`` group's options are :data:`frl.envs.TRAFFIC_PRESETS`, written into
    ``env.scenario``: the library holds each preset once, Hydra only names it.
    """
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    store.store(name="train_schema", node=TrainSchema)
    for name, values in TRAFFIC_PRESETS.items():
        store.store(group="traffic", name=name, node=dict(values), package="env.scenario")


# ------------------------------------------------------------------- validation
def validate(
    cfg: DictConfig | TrainSchema | dict[str, Any], this_machine: bool = True
) -> TrainSettings:
    """Check ``cfg`` and build the library configs; :class:`ConfigError` names the problem.

    Keys ``cfg`` leaves out take the schema's defaults. ``this_machine``: also check that
    ``cores`` and ``device`` exist here; a sweep submitted to a cluster (a Hydra launcher)
    leaves those to the machine each job runs on, which checks them before it trains.
    """
    data = _complete(cfg)
    federation = data["federation"]
    reward = dict(data["reward"])
    agent = dict(data["agent"])

    if federation["backend"] not in FEDERATION_BACKENDS:
        raise ConfigError(
            f"unknown federation.backend {federation['backend']!r}; "
            f"choose one of {', '.join(FEDERATION_BACKENDS)}"
        )
    if reward["name"] not in REWARD_NAMES:
        raise ConfigError(
            f"unknown reward {reward['name']!r}; choose one of {', '.join(REWARD_NAMES)}"
        )
    if agent.pop("name") != "ddpg":
        raise ConfigError("unknown agent; frl implements agent=ddpg only")
    budget_by_task = agent.pop("collision_budget_by_task", None) or None
    if data["seed"] < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {data['seed']!r}")
    if data["eval_episodes"] < 0:
        raise ConfigError(
            f"eval_episodes must be a non-negative integer, got {data['eval_episodes']!r}"
        )
    if data["round_test_episodes"] < 0:
        raise ConfigError(
            "round_test_episodes must be a non-negative integer (0: no per-round test), "
            f"got {data['round_test_episodes']!r}"
        )
    yardsticks = tuple(data["yardsticks"])
    unknown_yardsticks = [name for name in yardsticks if name not in YARDSTICKS]
    if unknown_yardsticks:
        raise ConfigError(
            f"unknown yardstick {unknown_yardsticks[0]!r}; choose from {', '.join(YARDSTICKS)}"
        )
    flower = _flower_settings(federation, this_machine)
    timeout = federation["worker_timeout_s"]
    if timeout is not None and not timeout > 0:
        raise ConfigError(f"federation.worker_timeout_s must be positive, got {timeout!r}")
    threads = federation["threads_per_worker"]
    if threads < 0:
        raise ConfigError(f"federation.threads_per_worker must be >= 0, got {threads!r}")
    device = check_device(data["device"]) if this_machine else data["device"]
    if data["config_version"] != CONFIG_VERSION:
        raise ConfigError(
            f"config_version={data['config_version']} is not this frl's ({CONFIG_VERSION}); "
            "saved runs are migrated when they are read"
        )
    interval_steps = _interval_steps(data["interval"], data["total_steps"], agent)
    cores = _check_cores(data["cores"], this_machine)
    try:
        plan = FederationPlan(
            scheme=federation["scheme"],
            tasks=tuple(federation["tasks"]),
            total_steps=data["total_steps"],
            interval=interval_steps,
            targets=federation["targets"],
            weighting=federation["weighting"],
            initial_model=federation["initial_model"],
            vehicles_per_task=federation["vehicles_per_task"],
            fraction_train=federation["fraction_train"],
            vehicles_per_round=federation["vehicles_per_round"],
        )
        strategy = StrategySpec(federation["strategy"], dict(federation["strategy_params"]))
        fleet_size = plan.fleet_size
        env_config = EnvConfig.from_dict(data["env"])
        reward_config = RewardConfig.from_dict(reward)
        agent_config = DDPGConfig.from_dict(agent, saved=False)
        check_teacher(agent_config.guide, env_config.route_observation)
    except (ValueError, TypeError) as error:
        raise ConfigError(str(error)) from error
    vehicle_envs = _vehicle_envs(env_config, fleet_size, federation)
    budget_by_task = _budget_by_task(budget_by_task, plan, agent_config)
    if plan.aggregates and strategy.needs_global_model and not plan.shares_initial_model:
        raise ConfigError(
            f"federation.strategy={strategy.name} steps from one global model; it needs "
            "federation.initial_model=shared"
        )
    try:
        stack_updates = resolve_stacking(
            federation["stack_updates"], agent_config, env_config, strategy,
            federation["backend"], str(device),
        )  # fmt: skip
    except ValueError as error:
        raise ConfigError(str(error)) from error
    if federation["workers"] < 0:
        raise ConfigError(f"federation.workers must be >= 0, got {federation['workers']!r}")
    if (
        federation["backend"] == "flower"
        and plan.aggregates
        and flower.min_clients > plan.vehicles_drawn
    ):
        raise ConfigError(
            f"federation.flower.min_clients={flower.min_clients} exceeds the "
            f"{plan.vehicles_drawn} vehicles that train each round"
        )
    return TrainSettings(
        plan=plan,
        env=env_config,
        reward=reward_config,
        agent=agent_config,
        seed=data["seed"],
        eval_episodes=data["eval_episodes"],
        yardsticks=yardsticks,
        device=device,
        backend=federation["backend"],
        worker_timeout_s=timeout,
        threads_per_worker=threads or None,
        flower=flower,
        cores=cores,
        strategy=strategy,
        vehicle_envs=vehicle_envs,
        workers=federation["workers"],
        stack_updates=stack_updates,
        round_test_episodes=data["round_test_episodes"],
        collision_budget_by_task=budget_by_task,
    )


def _interval_steps(interval: int, total_steps: int, agent: dict[str, Any]) -> int:
    """The environment steps of a round of ``interval`` updates, checked to make a round."""
    train_freq = agent.get("train_freq", 1)
    if not isinstance(train_freq, int) or isinstance(train_freq, bool) or train_freq < 1:
        return interval  # DDPGConfig refuses it in its own words
    if total_steps <= 0:
        return interval * train_freq  # FederationPlan refuses it in its own words
    slots = total_steps // train_freq if total_steps > 0 else 0
    if not 0 < interval <= slots:
        raise ConfigError(
            f"interval counts the updates between two aggregations (or checkpoints) and must "
            f"lie in [1, {slots:,}] "
            f"(total_steps={total_steps:,} / agent.train_freq={train_freq}), got {interval!r}"
        )
    return interval * train_freq


def _vehicle_envs(
    env: EnvConfig, fleet_size: int, federation: dict[str, Any]
) -> tuple[EnvConfig, ...] | None:
    """Each vehicle's environment under ``vehicle_traffic`` / ``vehicle_arrival_period_steps``
    (a non-IID fleet); None where every vehicle drives ``env``."""
    presets = federation["vehicle_traffic"]
    periods = federation["vehicle_arrival_period_steps"]
    if presets is None and periods is None:
        return None
    for key, values in (("vehicle_traffic", presets), ("vehicle_arrival_period_steps", periods)):
        if values is not None and len(values) != fleet_size:
            raise ConfigError(
                f"federation.{key} has {len(values)} entries for a fleet of {fleet_size} "
                f"vehicle{'s' * (fleet_size > 1)}; give one per vehicle"
            )
    envs = []
    for index in range(fleet_size):
        scenario = env.scenario
        if presets is not None:
            if presets[index] not in TRAFFIC_PRESETS:
                raise ConfigError(
                    f"unknown traffic preset {presets[index]!r} in federation.vehicle_traffic; "
                    f"choose from {', '.join(TRAFFIC_PRESETS)}"
                )
            scenario = dataclasses.replace(scenario, **TRAFFIC_PRESETS[presets[index]])
        if periods is not None:
            try:
                scenario = dataclasses.replace(
                    scenario, human_arrival_period_steps=float(periods[index])
                )
            except ValueError as error:
                raise ConfigError(f"federation.vehicle_arrival_period_steps: {error}") from None
        envs.append(dataclasses.replace(env, scenario=scenario))
    return tuple(envs)


def check_device(name: str) -> str:
    """``name`` if torch can use that device here, else a one-line :class:`ConfigError`.

    The networks and their updates run on it; SUMO and the replay buffer's storage stay
    on the CPU (docs/training.md). Checked before any run directory or process exists.
    """
    import torch

    try:
        device = torch.device(name)
    except (RuntimeError, ValueError) as error:
        first = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ConfigError(f"device={name!r} is not a torch device ({first})") from None
    if device.type == "cpu":
        return name
    backend = getattr(torch, device.type, None)
    is_available = getattr(backend, "is_available", None)
    if not callable(is_available) or not is_available():
        raise ConfigError(
            f"device={name!r}: torch here has no usable {device.type} device "
            f"(torch {torch.__version__}); use device=cpu"
        )
    count = getattr(backend, "device_count", None)
    available = count() if callable(count) else 1
    if device.index is not None and device.index >= available:
        raise ConfigError(
            f"device={name!r}: this machine has {available} {device.type} "
            f"device{'s' * (available != 1)} ({device.type}:0"
            f"{f' to {device.type}:{available - 1}' if available > 1 else ''})"
        )
    return name


def _check_cores(cores: int, this_machine: bool = True) -> int | None:
    """``cores`` as the run's core budget (None: all), or a ConfigError."""
    available = available_cores()
    if cores < 0:
        raise ConfigError(f"cores must be >= 0 (0: all {available} available), got {cores!r}")
    if cores > available and this_machine:
        # More threads than cores is the slowdown this setting exists to prevent.
        raise ConfigError(f"cores={cores} exceeds the {available} cores available to this process")
    return cores or None


def _flower_settings(federation: dict[str, Any], this_machine: bool = True) -> FlowerSettings:
    """Check ``federation.flower``; with ``backend=flower``, also that Flower is installed
    and (``this_machine``) that the SuperLink named answers."""
    keys = dict(federation["flower"])
    runtime = keys["runtime"]
    if runtime not in FLOWER_RUNTIMES:
        raise ConfigError(
            f"unknown federation.flower.runtime {runtime!r}; choose one of "
            f"{', '.join(FLOWER_RUNTIMES)}"
        )
    superlink = keys["superlink"]
    if superlink is not None and ":" not in superlink:
        raise ConfigError(f"federation.flower.superlink must be host:port, got {superlink!r}")
    if keys["min_clients"] < 1:
        raise ConfigError(
            f"federation.flower.min_clients must be >= 1, got {keys['min_clients']!r}"
        )
    if not keys["connect_timeout_s"] > 0:
        raise ConfigError(
            "federation.flower.connect_timeout_s must be positive, got "
            f"{keys['connect_timeout_s']!r}"
        )
    if federation["backend"] == "flower":
        _require_flower(runtime)
        if runtime == "deployment" and superlink is not None and this_machine:
            why = unreachable_reason(superlink)
            if why is not None:
                raise ConfigError(
                    f"federation.flower.superlink={superlink}: nothing answers there ({why}); "
                    "start the SuperLink first, or leave the key unset for a local federation"
                )
    return FlowerSettings(**keys)


def _require_flower(runtime: str) -> None:
    import importlib.util

    try:
        import flwr  # noqa: F401
    except ImportError:
        raise ConfigError(
            "federation.backend=flower needs Flower, which is not installed: "
            "pip install 'frl[flower]'"
        ) from None
    if runtime == "simulation" and importlib.util.find_spec("ray") is None:
        raise ConfigError(
            "federation.flower.runtime=simulation needs Ray (Flower's simulation engine): "
            "pip install 'frl[flower]'"
        )


def _budget_by_task(
    budgets: dict[str, float] | None, plan: FederationPlan, agent: DDPGConfig
) -> dict[str, float] | None:
    """``agent.collision_budget_by_task`` checked: one budget in [0, 1) per task of the
    fleet, on an agent that has a collision budget, in a scheme whose vehicles have tasks."""
    if budgets is None:
        return None
    key = "agent.collision_budget_by_task"
    if agent.collision_budget is None:
        raise ConfigError(
            f"{key} sets each task's collision budget: set agent.collision_budget too"
        )
    if plan.scheme == "central":
        raise ConfigError(f"{key} needs a vehicle per task; Central-DDPG's drives random tasks")
    if set(budgets) != set(plan.tasks):
        raise ConfigError(
            f"{key} must name each task of the fleet once ({', '.join(plan.tasks)}), "
            f"got {', '.join(map(str, budgets)) or 'none'}"
        )
    for task, budget in budgets.items():
        number = isinstance(budget, int | float) and not isinstance(budget, bool)
        if not (number and 0 <= budget < 1):
            raise ConfigError(
                f"{key}.{task} must lie in [0, 1) (collisions per episode), got {budget!r}"
            )
    return {task: float(budgets[task]) for task in plan.tasks}


def _complete(cfg: DictConfig | TrainSchema | dict[str, Any]) -> dict[str, Any]:
    """``cfg`` merged into the schema: every key present, every value of its type."""
    try:
        if isinstance(cfg, DictConfig):
            given: Any = cfg
        elif dataclasses.is_dataclass(cfg):
            given = OmegaConf.structured(cfg)
        else:
            given = OmegaConf.create(dict(cfg))
        merged = OmegaConf.merge(OmegaConf.structured(TrainSchema), given)
        return OmegaConf.to_container(merged, resolve=True)  # type: ignore[return-value]
    except OmegaConfBaseException as error:
        raise ConfigError(one_line_error(error)) from None


def one_line_error(error: BaseException) -> str:
    """Hydra's or OmegaConf's message, with its cause, in one line without context lines."""
    parts: list[str] = []
    key = None
    for link in (error, error.__cause__):
        if link is None:
            continue
        lines = [line.strip() for line in str(link).splitlines() if line.strip()]
        key = key or next((line for line in lines if line.startswith("full_key:")), None)
        text = next(
            (line for line in lines if not line.startswith(("full_key:", "object_type"))), ""
        )
        if text and text not in parts:
            parts.append(text)
    message = ": ".join(parts) or type(error).__name__
    return f"{message} ({key})" if key and key != "full_key:" else message


def load_run_config(run_dir: str | Path) -> DictConfig:
    """The resolved config a run saved (``RUN_DIR/config.yaml``), checked against the schema.

    Configs saved before a key existed are read as they ran (:func:`migrate_saved_config`).
    """
    try:
        saved = read_saved_config(Path(run_dir))
    except ValueError as error:
        raise ConfigError(str(error)) from None
    try:
        merged = OmegaConf.merge(OmegaConf.structured(TrainSchema), migrate_saved_config(saved))
    except OmegaConfBaseException as error:
        raise ConfigError(f"{run_dir}/config.yaml: {one_line_error(error)}") from None
    return merged  # type: ignore[return-value]


def _interval_in_updates(saved: dict[str, Any]) -> dict[str, Any]:
    agent = saved.get("agent") if isinstance(saved.get("agent"), dict) else {}
    train_freq = agent.get("train_freq", 1)
    interval = saved.get("interval")
    if isinstance(interval, int) and isinstance(train_freq, int) and train_freq > 0:
        if interval % train_freq:
            raise ConfigError(
                f"this run's rounds of {interval:,} environment steps are not a whole number "
                f"of updates at agent.train_freq={train_freq}; frl now counts interval in "
                "updates and cannot read it"
            )
        saved["interval"] = interval // train_freq
    return {**saved, "config_version": CONFIG_VERSION}


def complete_saved_config(saved: dict[str, Any]) -> dict[str, Any]:
    """A saved run config as today's schema reads it: migrated
    (:func:`migrate_saved_config`), every key present. Two runs of one setting, saved by
    different frl versions, compare equal."""
    return _complete(migrate_saved_config(saved))


RETIRED_OUTSIDE_AGENT: dict[str, dict[str, RetiredOption]] = {
    "env": RETIRED_ENV_OPTIONS,
    "reward": RETIRED_REWARD_OPTIONS,
    "federation": RETIRED_FEDERATION_OPTIONS,
}
"""The retired options of each config group but the agent's, whose table
(:mod:`frl.agents.retired`) also holds its nested groups' (:mod:`frl.retirement`)."""


PROBE_RETIREMENT = (
    'was retired: docs/studies.md, "A collision budget", measured the counterfactual probe '
    "as not helping, and commit 9b53480 holds its code; only probe.rate=0 (off) still loads"
)
"""Why a run config with the counterfactual probe on is refused."""


def migrate_saved_config(saved: dict[str, Any]) -> dict[str, Any]:
    """A run config saved by an earlier frl, with the settings it actually ran with.

    - No ``env.scenario.human_speed_dev``: humans had no speed deviation then (0.0), where
      today's default is the paper preset's 0.1.
    - ``eval_arrival_period_steps``: tests ran on their own traffic setting; they now run
      on ``env.scenario``. Every run saved with it tested on its training density, so the
      key is dropped; one that differs cannot be re-tested as it was, and is refused.
    - No ``yardsticks``: none were tested; re-testing such a run adds today's default.
    - The ``agent`` as it ran (:func:`frl.agents.config.agent_fields_as_run`): without
      n-step targets or held warm-up actions where it lacks them, today's default having
      both; retired options at their off values dropped, a run that used one refused in
      one line; keys that moved into groups (``noise_sigma``: ``noise.sigma``) moved.
    - Retired env, reward and federation options
      (:data:`frl.envs.config.RETIRED_ENV_OPTIONS`, ...) likewise: dropped at their off
      values, refused at any other.
    - No ``config_version`` (format 1): ``interval`` counted environment steps; it becomes
      the updates of those steps (``interval / agent.train_freq``), the same rounds.
    - ``probe``: the counterfactual probe, retired (:data:`PROBE_RETIREMENT`). Saved off
      (``rate: 0``) it is dropped; a run that probed is refused in one line.
    """
    saved = dict(saved)
    if "config_version" not in saved:
        saved = _interval_in_updates(saved)
    if isinstance(saved.get("agent"), dict):
        try:
            saved["agent"] = agent_fields_as_run(saved["agent"])
        except RetiredOptionError as error:
            raise ConfigError(str(error)) from None
    try:  # env, reward and federation options retired as the agent's are
        for group, retired in RETIRED_OUTSIDE_AGENT.items():
            if isinstance(saved.get(group), dict):
                saved[group] = without_retired(saved[group], retired, group)
    except RetiredOptionError as error:
        raise ConfigError(str(error)) from None
    env = dict(saved.get("env") or {})
    scenario = dict(env.get("scenario") or {})
    if scenario and "human_speed_dev" not in scenario:
        scenario["human_speed_dev"] = 0.0
        env["scenario"] = scenario
        saved["env"] = env
    if "probe" in saved:
        probe = saved.pop("probe")
        rate = probe.get("rate", 0.0) if isinstance(probe, dict) else probe
        if rate != 0:
            raise ConfigError(f"probe.rate={rate!r} {PROBE_RETIREMENT}")
    if "eval_arrival_period_steps" in saved:
        test_period = saved.pop("eval_arrival_period_steps")
        train_period = scenario.get("human_arrival_period_steps", test_period)
        if float(test_period) != float(train_period):
            raise ConfigError(
                f"this run tested on other traffic (eval_arrival_period_steps={test_period}) "
                f"than it trained on ({train_period}); frl now tests on the training traffic"
            )
    return saved
