"""The training configuration: Hydra schemas, their validation and the library configs.

The schema dataclasses below are registered in Hydra's ConfigStore (``train_schema``)
and are the root of ``conf/config.yaml``, so a typo (``agent.lrr=1``) or a wrong type
(``interval=abc``) fails while Hydra composes the config, before anything runs. Their
defaults are read from the library dataclasses, which remain the single source of truth.

:func:`validate` then checks what a schema cannot (``interval`` within the budget, known
scheme, tasks and reward, ranges) and builds the typed library configs; it raises
:class:`ConfigError` before any process starts. Library classes never see a DictConfig.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from frl.agents import DDPGConfig
from frl.agents.config import FIELDS_ADDED_LATER
from frl.envs import TASKS, EnvConfig, GridConfig, RewardConfig, ScenarioConfig
from frl.envs.config import REWARD_NAMES, TRAFFIC_PRESETS
from frl.federation.plan import BACKENDS, FLOWER_RUNTIMES, FederationPlan
from frl.policies import YARDSTICKS

_ENV = EnvConfig()
_SCENARIO = ScenarioConfig()
_GRID = GridConfig()
_AGENT = DDPGConfig()
_REWARD = RewardConfig()


class ConfigError(ValueError):
    """The configuration is invalid; raised before any worker or SUMO starts."""


# ---------------------------------------------------------------- Hydra schemas
@dataclass
class ScenarioSchema:
    """:class:`frl.envs.ScenarioConfig` (docs/scenario.md)."""

    arm_length: float = _SCENARIO.arm_length
    lane_width: float = _SCENARIO.lane_width
    speed_limit: float = _SCENARIO.speed_limit
    step_length: float = _SCENARIO.step_length
    human_arrival_period_steps: float = _SCENARIO.human_arrival_period_steps
    human_arrival_process: str = _SCENARIO.human_arrival_process
    human_speed_dev: float = _SCENARIO.human_speed_dev
    ego_start_distance: float = _SCENARIO.ego_start_distance
    ego_destination_distance: float = _SCENARIO.ego_destination_distance
    vehicle_length: float = _SCENARIO.vehicle_length
    vehicle_width: float = _SCENARIO.vehicle_width


@dataclass
class GridSchema:
    """:class:`frl.envs.GridConfig`: the Eq. (1) observation grid."""

    lateral_range: list[float] = field(default_factory=lambda: list(_GRID.lateral_range))
    lateral_cells: int = _GRID.lateral_cells
    longitudinal_range: list[float] = field(default_factory=lambda: list(_GRID.longitudinal_range))
    longitudinal_cells: int = _GRID.longitudinal_cells
    speed_scale: float = _GRID.speed_scale
    heading_scale_deg: float = _GRID.heading_scale_deg


@dataclass
class EnvSchema:
    """:class:`frl.envs.EnvConfig` without ``task``, which the scheme decides."""

    max_episode_steps: int = _ENV.max_episode_steps
    accel_scale: float = _ENV.accel_scale
    warmup_steps: int = _ENV.warmup_steps
    backend: str = _ENV.backend
    scenario: ScenarioSchema = field(default_factory=ScenarioSchema)
    grid: GridSchema = field(default_factory=GridSchema)


@dataclass
class AgentSchema:
    """:class:`frl.agents.DDPGConfig` (the paper's Table II) plus the algorithm's name."""

    name: str = "ddpg"
    hidden_sizes: list[int] = field(default_factory=lambda: list(_AGENT.hidden_sizes))
    buffer_size: int = _AGENT.buffer_size
    learning_starts: int = _AGENT.learning_starts
    batch_size: int = _AGENT.batch_size
    tau: float = _AGENT.tau
    gamma: float = _AGENT.gamma
    actor_lr: float = _AGENT.actor_lr
    critic_lr: float = _AGENT.critic_lr
    train_freq: int = _AGENT.train_freq
    gradient_steps: int = _AGENT.gradient_steps
    noise: str = _AGENT.noise
    noise_sigma: float = _AGENT.noise_sigma
    noise_theta: float = _AGENT.noise_theta
    noise_dt: float = _AGENT.noise_dt
    random_warmup: bool = _AGENT.random_warmup
    warmup_hold_steps: float = _AGENT.warmup_hold_steps
    n_step: int = _AGENT.n_step
    preactivation_l2: float = _AGENT.preactivation_l2
    sparse_input: Any = _AGENT.sparse_input
    """true, false or auto (OmegaConf has no bool-or-str type; checked by DDPGConfig)."""
    sparse_min_features: int = _AGENT.sparse_min_features
    sparse_capacity: int = _AGENT.sparse_capacity


@dataclass
class RewardSchema:
    """:class:`frl.envs.RewardConfig`; ``conf/reward/*.yaml`` hold the named presets."""

    name: str = _REWARD.name
    alpha: float = _REWARD.alpha
    beta: float = _REWARD.beta
    gamma: float = _REWARD.gamma
    undisturbed_bonus: float = _REWARD.undisturbed_bonus
    lambda_: float = _REWARD.lambda_
    mu: float = _REWARD.mu
    disturbance_radius: float = _REWARD.disturbance_radius
    moving_speed: float = _REWARD.moving_speed


@dataclass
class FlowerSchema:
    """``federation.backend=flower``: the runtime and the failure policy (docs/flower.md)."""

    runtime: str = "simulation"
    """simulation (one machine) | deployment (SuperLink + one SuperNode per vehicle)."""
    superlink: Any = None
    """deployment: null starts a SuperLink and the SuperNodes on 127.0.0.1; "host:port"
    submits to a running SuperLink whose SuperNodes run python -m frl.flower.node."""
    accept_failures: bool = True
    """A vehicle that fails is dropped and the round goes on (fedavg only), as Flower's FedAvg."""
    min_clients: int = 2
    """Fewest vehicles that must answer for the run to go on (fedavg)."""
    connect_timeout_s: float = 300.0
    """Longest wait for every vehicle's SuperNode to connect."""


@dataclass
class FederationSchema:
    """The scheme (:class:`frl.federation.FederationPlan`) and how clients run."""

    scheme: str = "fedavg"
    """central | separate | fedavg."""
    tasks: list[str] = field(default_factory=lambda: list(TASKS))
    targets: str = "average"
    """average: targets averaged too; resync: onlines averaged, then copied to targets."""
    weighting: str = "equal"
    """equal: Eq. (3); steps: weighted by the clients' steps in the round."""
    initial_model: str | None = None
    """shared: all clients start from one initial model; independent: each its own;
    null: shared for fedavg, independent otherwise."""
    backend: str = "processes"
    """processes: one spawned worker process per client (one SUMO each); flower: Flower."""
    flower: FlowerSchema = field(default_factory=FlowerSchema)
    worker_timeout_s: float = 3600.0
    """Longest one worker call (a round of local training) may take before the run stops."""
    threads_per_worker: int = 0
    """Torch threads per worker; 0: the available cores split evenly over the workers."""


@dataclass
class TrainSchema:
    """Root of ``conf/config.yaml``. Budget and cadence are root keys: ``interval=2000``."""

    seed: int = 0
    total_steps: int = 10_000
    """Environment steps per agent (the paper's budget)."""
    interval: int = 2_000
    """Environment steps per client between aggregations (FedAvg) or checkpoints (all)."""
    eval_episodes: int = 100
    """Test episodes per task after training (Section IV.B); 0 skips evaluation. Tests
    run on the training traffic (``env.scenario``, set by the ``traffic`` group)."""
    yardsticks: list[str] = field(default_factory=lambda: ["full_throttle", "oracle"])
    """Yardstick policies tested on the same seeds beside the model (frl.policies)."""
    progress: bool = True
    """Progress bar; always off in multirun."""
    resume: Any = False
    """false; true (the newest unfinished run under outputs/, or run_dir); a run dir; or
    auto (the run in run_dir: continued if unfinished, skipped if finished, else started)."""
    device: str = "cpu"
    run_dir: Any = None
    """Where the run writes; null: Hydra's output directory."""
    env: EnvSchema = field(default_factory=EnvSchema)
    agent: AgentSchema = field(default_factory=AgentSchema)
    federation: FederationSchema = field(default_factory=FederationSchema)
    reward: RewardSchema = field(default_factory=RewardSchema)


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
@dataclass(frozen=True)
class FlowerSettings:
    """The validated ``federation.flower`` keys."""

    runtime: str = "simulation"
    superlink: str | None = None
    accept_failures: bool = True
    min_clients: int = 2
    connect_timeout_s: float = 300.0


@dataclass(frozen=True)
class TrainSettings:
    """A validated configuration, as typed library objects."""

    plan: FederationPlan
    env: EnvConfig
    reward: RewardConfig
    agent: DDPGConfig
    seed: int
    eval_episodes: int
    yardsticks: tuple[str, ...]
    device: str
    backend: str
    worker_timeout_s: float | None
    threads_per_worker: int | None
    flower: FlowerSettings = field(default_factory=FlowerSettings)

    def eval_env(self, task: str) -> EnvConfig:
        """The test environment of ``task``: the training traffic (Section IV.B)."""
        return dataclasses.replace(self.env, task=task)


def validate(cfg: DictConfig | TrainSchema | dict[str, Any]) -> TrainSettings:
    """Check ``cfg`` and build the library configs; :class:`ConfigError` names the problem."""
    data = _to_container(cfg)
    unknown = sorted(set(data) - {f.name for f in dataclasses.fields(TrainSchema)})
    if unknown:
        raise ConfigError(f"unknown config key {unknown[0]!r}")
    federation = data.get("federation", {})
    reward = dict(data.get("reward", {}))
    agent = dict(data.get("agent", {}))
    env = dict(data.get("env", {}))

    if federation.get("backend", "processes") not in BACKENDS:
        raise ConfigError(
            f"unknown federation.backend {federation.get('backend')!r}; "
            f"choose one of {', '.join(BACKENDS)}"
        )
    if reward.get("name", "paper") not in REWARD_NAMES:
        raise ConfigError(
            f"unknown reward {reward.get('name')!r}; choose one of {', '.join(REWARD_NAMES)}"
        )
    if agent.pop("name", "ddpg") != "ddpg":
        raise ConfigError("unknown agent; frl implements agent=ddpg only")
    for key in ("eval_episodes",):
        value = data.get(key, 0)
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            raise ConfigError(f"{key} must be a non-negative integer, got {value!r}")
    yardsticks = tuple(data.get("yardsticks", ()))
    unknown_yardsticks = [name for name in yardsticks if name not in YARDSTICKS]
    if unknown_yardsticks:
        raise ConfigError(
            f"unknown yardstick {unknown_yardsticks[0]!r}; choose from {', '.join(YARDSTICKS)}"
        )
    flower = _flower_settings(federation)
    timeout = federation.get("worker_timeout_s", 3600.0)
    if timeout is not None and not timeout > 0:
        raise ConfigError(f"federation.worker_timeout_s must be positive, got {timeout!r}")
    threads = federation.get("threads_per_worker", 0)
    if not isinstance(threads, int) or threads < 0:
        raise ConfigError(f"federation.threads_per_worker must be >= 0, got {threads!r}")
    try:
        plan = FederationPlan(
            scheme=federation.get("scheme", "fedavg"),
            tasks=tuple(federation.get("tasks", TASKS)),
            total_steps=data.get("total_steps", 10_000),
            interval=data.get("interval", 2_000),
            targets=federation.get("targets", "average"),
            weighting=federation.get("weighting", "equal"),
            initial_model=federation.get("initial_model"),
        )
        scenario = ScenarioConfig(**env.pop("scenario", {}))
        grid_fields = dict(env.pop("grid", {}))
        for name in ("lateral_range", "longitudinal_range"):
            if name in grid_fields:
                grid_fields[name] = tuple(grid_fields[name])
        env_config = EnvConfig(scenario=scenario, grid=GridConfig(**grid_fields), **env)
        reward_config = RewardConfig(**reward)
        agent_config = DDPGConfig.from_dict(agent)
    except (ValueError, TypeError) as error:
        raise ConfigError(str(error)) from error
    if (
        federation.get("backend") == "flower"
        and plan.aggregates
        and flower.min_clients > len(plan.client_tasks)
    ):
        raise ConfigError(
            f"federation.flower.min_clients={flower.min_clients} exceeds the "
            f"{len(plan.client_tasks)} clients of the run"
        )
    return TrainSettings(
        plan=plan,
        env=env_config,
        reward=reward_config,
        agent=agent_config,
        seed=int(data.get("seed", 0)),
        eval_episodes=int(data.get("eval_episodes", 100)),
        yardsticks=yardsticks,
        device=str(data.get("device", "cpu")),
        backend=federation.get("backend", "processes"),
        worker_timeout_s=timeout,
        threads_per_worker=threads or None,
        flower=flower,
    )


def _flower_settings(federation: dict[str, Any]) -> FlowerSettings:
    """Check ``federation.flower``; with ``backend=flower``, also that Flower is installed."""
    keys = dict(federation.get("flower") or {})
    runtime = keys.get("runtime", "simulation")
    if runtime not in FLOWER_RUNTIMES:
        raise ConfigError(
            f"unknown federation.flower.runtime {runtime!r}; choose one of "
            f"{', '.join(FLOWER_RUNTIMES)}"
        )
    superlink = keys.get("superlink")
    if superlink is not None and (not isinstance(superlink, str) or ":" not in superlink):
        raise ConfigError(f"federation.flower.superlink must be host:port, got {superlink!r}")
    min_clients = keys.get("min_clients", 2)
    if not isinstance(min_clients, int) or isinstance(min_clients, bool) or min_clients < 1:
        raise ConfigError(f"federation.flower.min_clients must be >= 1, got {min_clients!r}")
    connect_timeout = keys.get("connect_timeout_s", 300.0)
    if not connect_timeout > 0:
        raise ConfigError(
            f"federation.flower.connect_timeout_s must be positive, got {connect_timeout!r}"
        )
    if federation.get("backend") == "flower":
        _require_flower(runtime)
    return FlowerSettings(
        runtime=runtime,
        superlink=superlink,
        accept_failures=bool(keys.get("accept_failures", True)),
        min_clients=min_clients,
        connect_timeout_s=float(connect_timeout),
    )


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


def _to_container(cfg: DictConfig | TrainSchema | dict[str, Any]) -> dict[str, Any]:
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    if dataclasses.is_dataclass(cfg):
        return OmegaConf.to_container(OmegaConf.structured(cfg), resolve=True)  # type: ignore[return-value]
    return dict(cfg)


def load_run_config(run_dir: str | Path) -> DictConfig:
    """The resolved config a run saved (``RUN_DIR/config.yaml``), checked against the schema.

    Configs saved before a key existed are read as they ran (:func:`migrate_saved_config`).
    """
    path = Path(run_dir) / "config.yaml"
    if not path.exists():
        raise ConfigError(f"{run_dir} is not an frl run directory: it has no config.yaml")
    saved = OmegaConf.to_container(OmegaConf.load(path), resolve=True)
    if not isinstance(saved, dict):
        raise ConfigError(f"{path} is not an frl run config")
    schema = OmegaConf.structured(TrainSchema)
    return OmegaConf.merge(schema, migrate_saved_config(saved))  # type: ignore[return-value]


def migrate_saved_config(saved: dict[str, Any]) -> dict[str, Any]:
    """A run config saved by an earlier frl, with the settings it actually ran with.

    - No ``env.scenario.human_speed_dev``: humans had no speed deviation then (0.0), where
      today's default is the paper preset's 0.1.
    - ``eval_arrival_period_steps``: tests ran on their own traffic setting; they now run
      on ``env.scenario``. Every run saved with it tested on its training density, so the
      key is dropped; one that differs cannot be re-tested as it was, and is refused.
    - No ``yardsticks``: none were tested; re-testing such a run adds today's default.
    - An ``agent`` without n-step targets or held warm-up actions ran without them
      (:data:`frl.agents.config.FIELDS_ADDED_LATER`), where today's default has both.
    """
    saved = dict(saved)
    if isinstance(saved.get("agent"), dict):
        saved["agent"] = {**FIELDS_ADDED_LATER, **saved["agent"]}
    env = dict(saved.get("env") or {})
    scenario = dict(env.get("scenario") or {})
    if scenario and "human_speed_dev" not in scenario:
        scenario["human_speed_dev"] = 0.0
        env["scenario"] = scenario
        saved["env"] = env
    if "eval_arrival_period_steps" in saved:
        test_period = saved.pop("eval_arrival_period_steps")
        train_period = scenario.get("human_arrival_period_steps", test_period)
        if float(test_period) != float(train_period):
            raise ConfigError(
                f"this run tested on other traffic (eval_arrival_period_steps={test_period}) "
                f"than it trained on ({train_period}); frl now tests on the training traffic"
            )
    return saved
