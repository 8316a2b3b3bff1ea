"""Typed, validated configuration of the intersection scenario, its observation and reward.

Every choice the paper leaves open is a field here, with the value that reproduces the
paper's scale (see docs/scenario.md). Library classes take these dataclasses, never a
Hydra ``DictConfig``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

from frl.retirement import RetiredOption, without_retired

TASKS: tuple[str, ...] = ("left", "straight", "right")
"""The agent's three routes at the intersection (paper, Section III.A)."""

TASK_CHOICES: tuple[str, ...] = (*TASKS, "random")
"""Valid values of ``EnvConfig.task``; ``random`` draws one of TASKS per episode."""

SUMO_BACKENDS: tuple[str, ...] = ("libsumo", "traci")
ARRIVAL_PROCESSES: tuple[str, ...] = ("bernoulli", "poisson", "periodic")
REWARD_NAMES: tuple[str, ...] = ("paper", "reference")

SPEED_LIMIT_MPS = 20.1168
"""45 mph, the maximum speed of both vehicle types in the paper's Table I."""


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _finite(name: str, value: float) -> None:
    _require(isinstance(value, (int, float)) and math.isfinite(value), f"{name} must be finite")


@dataclass(frozen=True)
class GridConfig:
    """The ego-centric occupancy grid of the paper's Eq. (1)."""

    lateral_range: tuple[float, float] = (-80.0, 80.0)
    """Metres across the ego's heading (negative = left), covered by ``lateral_cells``."""
    lateral_cells: int = 26
    longitudinal_range: tuple[float, float] = (-5.0, 40.0)
    """Metres along the ego's heading (negative = behind), covered by ``longitudinal_cells``."""
    longitudinal_cells: int = 18
    speed_scale: float = 20.0
    """Speeds are divided by this (m/s); 20 m/s maps the speed limit to about 1."""
    heading_scale_deg: float = 90.0
    """Relative headings in (-180, 180] degrees are divided by this."""

    def __post_init__(self) -> None:
        for name in ("lateral_range", "longitudinal_range"):
            low, high = getattr(self, name)
            _finite(f"grid.{name}", low)
            _finite(f"grid.{name}", high)
            _require(high > low, f"grid.{name} must be a non-empty range, got ({low}, {high})")
        for name in ("lateral_cells", "longitudinal_cells"):
            value = getattr(self, name)
            _require(
                isinstance(value, int) and value > 0, f"grid.{name} must be a positive integer"
            )
        _require(self.speed_scale > 0, "grid.speed_scale must be positive")
        _require(self.heading_scale_deg > 0, "grid.heading_scale_deg must be positive")

    @property
    def shape(self) -> tuple[int, int, int]:
        """Observation shape: (lateral cells, longitudinal cells, 3 channels)."""
        return (self.lateral_cells, self.longitudinal_cells, 3)


@dataclass(frozen=True)
class ScenarioConfig:
    """What SUMO simulates: the network, the human traffic and the SUMO options.

    Fields that shape the generated files are hashed into the scenario cache key
    (see :func:`frl.envs.scenario.build_scenario`).
    """

    arm_length: float = 100.0
    """Length (m) of each of the four arms, centre to end. Humans depart at the far end."""
    lane_width: float = 4.0
    """The scenario's lineage uses 4.0 m lanes (``dense`` keeps SUMO's default 3.2 m)."""
    speed_limit: float = SPEED_LIMIT_MPS
    step_length: float = 0.2
    """SUMO step length in seconds: one environment step."""
    human_arrival_period_steps: float = 25.0
    """Mean steps between two human departures, both flows (west->east, east->west) together.

    Each flow gets half the rate: 25 steps of 0.2 s are one car per 10 s per flow, the
    lineage's ``probability="0.1"`` (docs/scenario.md). ``dense`` uses 10.
    """
    human_arrival_process: str = "bernoulli"
    """How each flow departs, at the mean rate above:

    - ``bernoulli``: SUMO's flow ``probability``, a departure chance every step scaled to
      a probability per second, as in the scenario's lineage;
    - ``poisson``: exponential headways (SUMO ``period="exp(rate)"``);
    - ``periodic``: one car every period exactly.
    """
    human_speed_dev: float = 0.1
    """SUMO ``speedDev`` of the human type: each car's speed factor is drawn from
    N(1, dev) (clipped by SUMO to [0.2, 2]). The lineage uses 0.1; ``dense`` uses 0."""
    ego_start_distance: float = 10.0
    """The ego departs this far (m, front bumper) before the stop line, at speed 0."""
    ego_destination_distance: float = 21.0
    """The episode ends in success when the ego's front is this far (m) past the centre."""
    vehicle_length: float = 5.0
    vehicle_width: float = 1.8

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float | int) and not isinstance(value, bool):
                _finite(f"scenario.{f.name}", value)
        _require(self.arm_length >= 50.0, "scenario.arm_length must be at least 50 m")
        _require(self.lane_width > 0, "scenario.lane_width must be positive")
        _require(self.speed_limit > 0, "scenario.speed_limit must be positive")
        _require(self.step_length > 0, "scenario.step_length must be positive")
        _require(
            self.human_arrival_period_steps > 0,
            "scenario.human_arrival_period_steps must be positive "
            f"(got {self.human_arrival_period_steps})",
        )
        _require(self.human_speed_dev >= 0, "scenario.human_speed_dev must be >= 0")
        _require(
            self.human_arrival_process != "bernoulli" or self.human_period_seconds >= 1.0,
            "scenario.human_arrival_process=bernoulli needs at most one departure per second "
            f"per flow; human_arrival_period_steps={self.human_arrival_period_steps} asks for "
            f"one per {self.human_period_seconds:g} s",
        )
        _require(
            self.human_arrival_process in ARRIVAL_PROCESSES,
            f"scenario.human_arrival_process must be one of {ARRIVAL_PROCESSES}, "
            f"got {self.human_arrival_process!r}",
        )
        _require(
            0 < self.ego_start_distance < self.arm_length - 2 * self.vehicle_length,
            "scenario.ego_start_distance must leave room on the arm",
        )
        _require(
            self.lane_width < self.ego_destination_distance < self.arm_length - 1.0,
            "scenario.ego_destination_distance must lie on the exit arm",
        )
        _require(self.vehicle_length > 0, "scenario.vehicle_length must be positive")
        _require(self.vehicle_width > 0, "scenario.vehicle_width must be positive")

    @property
    def human_period_seconds(self) -> float:
        """Mean headway of each of the two human flows in seconds (SUMO periods are seconds)."""
        return 2.0 * self.human_arrival_period_steps * self.step_length


TRAFFIC_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {
        "lane_width": 4.0,
        "human_arrival_period_steps": 25.0,
        "human_arrival_process": "bernoulli",
        "human_speed_dev": 0.1,
    },
    "dense": {
        "lane_width": 3.2,
        "human_arrival_period_steps": 10.0,
        "human_arrival_process": "poisson",
        "human_speed_dev": 0.0,
    },
}
"""The human traffic, by name (docs/scenario.md has the evidence for each):

- ``paper`` (the default): one car per 10 s per flow, 4.0 m lanes, speed deviation 0.1,
  the traffic of the scenario's lineage, whose numbers match the paper's;
- ``dense``: one car per 4 s per flow, 3.2 m lanes, no speed deviation: frl's traffic
  before the calibration (the first edition, docs/results/edition1.md), a harder setting.

``python -m frl.train traffic=dense`` selects one; fields stay overridable.
"""


def traffic_preset(name: str, **overrides: Any) -> ScenarioConfig:
    """The :class:`ScenarioConfig` of the traffic preset ``name``, with field overrides."""
    _require(
        name in TRAFFIC_PRESETS,
        f"unknown traffic preset {name!r}; choose one of {', '.join(TRAFFIC_PRESETS)}",
    )
    return ScenarioConfig(**{**TRAFFIC_PRESETS[name], **overrides})


def traffic_name(scenario: ScenarioConfig) -> str:
    """The preset whose traffic ``scenario`` has, or ``custom`` (for tables and reports)."""
    for name, values in TRAFFIC_PRESETS.items():
        if all(getattr(scenario, key) == value for key, value in values.items()):
            return name
    return "custom"


RETIRED_REWARD_OPTIONS: dict[str, RetiredOption] = {
    "brake_past_line_cost": RetiredOption(
        0.0, '"Where the car stands: the committed rule and the junction in view"', "29f9775"
    ),
}
"""Reward options that frl retired (:mod:`frl.retirement`)."""

RETIRED_ENV_OPTIONS: dict[str, RetiredOption] = {
    "commit_at_line": RetiredOption(
        False, '"Where the car stands: the committed rule and the junction in view"', "376e884"
    ),
    "windows_until_committed": RetiredOption(
        False, '"Where the car stands: the committed rule and the junction in view"', "6591107"
    ),
}
"""Env options that frl retired (:mod:`frl.retirement`)."""


@dataclass(frozen=True)
class RewardConfig:
    """Per-step reward r = alpha*t + beta*v + gamma*(b + w) + kappa*u + lambda*c + mu*d.

    Terms, each evaluated after the simulation step:

    - ``t`` = 1 every step (time cost).
    - ``v`` = 1 while the ego moves (speed > ``moving_speed``), else 0.
    - ``b`` = 1 if at least one human within ``disturbance_radius`` of the ego has its
      brake-light bit set (``signals & 8``), else 0.
    - ``w`` = 1 if at least one human within ``disturbance_radius`` is waiting
      (speed <= ``moving_speed``), else 0.
    - ``u`` = 1 if neither ``b`` nor ``w`` is set (nobody disturbed), else 0. Its weight
      ``kappa`` (``undisturbed_bonus``) is the +0.05 of the scenario's lineage that makes a
      clean pass score about 6-7 as in the paper; set it to 0 for Eq. (2) alone.
    - ``c`` = 1 on the step the ego appears in SUMO's colliding-vehicle list, else 0.
    - ``d`` = 1 on the step the ego arrives at its destination, else 0.

    Humans ignore one another's right of way and keep safe following gaps only to
    their leader, so a human near the ego that brakes or waits does so because of the
    ego: proximity is how ``b`` and ``w`` are attributed to the agent.

    ``name="reference"`` selects the reward of the paper's Section IV.A comparison:
    -0.01 per step, -1 on collision, +1 on success, and all other weights zero.
    """

    name: str = "paper"
    alpha: float = -0.05
    beta: float = 0.04
    gamma: float = -0.025
    undisturbed_bonus: float = 0.05
    lambda_: float = -10.0
    mu: float = 5.0
    disturbance_radius: float = 20.0
    """Humans closer than this (m, front bumpers) to the ego count for ``b`` and ``w``."""
    moving_speed: float = 0.1
    """Speeds at or below this (m/s) count as standing still."""

    def __post_init__(self) -> None:
        _require(
            self.name in REWARD_NAMES,
            f"reward.name must be one of {REWARD_NAMES}, got {self.name!r}",
        )
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float | int) and not isinstance(value, bool):
                _finite(f"reward.{f.name}", value)
        _require(self.disturbance_radius >= 0, "reward.disturbance_radius must be >= 0")
        _require(self.moving_speed >= 0, "reward.moving_speed must be >= 0")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RewardConfig:
        """A :class:`RewardConfig` from plain data (a saved config, a JSON spec); a retired
        option (:data:`RETIRED_REWARD_OPTIONS`) loads only at its off value.

        Raises:
            frl.retirement.RetiredOptionError: a retired option at any other value.
        """
        return cls(**without_retired(data, RETIRED_REWARD_OPTIONS, "reward"))

    @classmethod
    def reference(cls) -> RewardConfig:
        """The Section IV.A reference reward: -0.01/step, -1 collision, +1 success."""
        return cls(
            name="reference",
            alpha=-0.01,
            beta=0.0,
            gamma=0.0,
            undisturbed_bonus=0.0,
            lambda_=-1.0,
            mu=1.0,
        )

    @classmethod
    def named(cls, name: str, **overrides: Any) -> RewardConfig:
        """The reward preset ``name`` (``paper`` or ``reference``) with field overrides."""
        _require(name in REWARD_NAMES, f"unknown reward {name!r}; choose one of {REWARD_NAMES}")
        base = cls.reference() if name == "reference" else cls()
        return replace(base, **overrides)


@dataclass(frozen=True)
class EnvConfig:
    """Everything :class:`frl.envs.IntersectionEnv` needs besides the reward."""

    task: str = "straight"
    """``left``, ``straight``, ``right``, or ``random`` (one drawn per episode)."""
    max_episode_steps: int = 200
    """Episodes still running after this many steps are truncated."""
    accel_scale: float = 1.0
    """An action a in [-1, 1] is an acceleration of ``a * accel_scale`` m/s^2."""
    warmup_steps: int = 60
    """Steps SUMO runs after a (re)start before the ego departs, so cross traffic is flowing."""
    backend: str = "libsumo"
    """``libsumo`` (in-process, fast, one per process) or ``traci`` (socket, sumo-gui)."""
    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    route_observation: bool = False
    """Observe the ego's route beside the grid: a Dict observation ``{"grid": Eq. (1),
    "route": [left, straight, right, distance to the stop line / 10 m]}``, the task one-hot
    and the distance along the route (negative past the line). Before the junction the
    grid looks the same for every task, where a car in the far lane matters going
    straight or left and not turning right; off (the paper's observation): the grid alone."""
    window_observation: bool = False
    """Observe the grid's crossing cars as time windows beside the grid: a Dict observation
    with a ``windows`` part (after ``route`` where both are on), per side of the ego the
    binding crossing car's window on its path and the ego's window on that car's lane
    (:meth:`frl.envs.conflicts.CrossingReader.features`). Read from the grid alone, as the
    gap-acceptance rule reads it; off: no such part."""

    def __post_init__(self) -> None:
        _require(
            self.task in TASK_CHOICES,
            f"unknown task {self.task!r}; choose one of {TASK_CHOICES}",
        )
        _require(
            isinstance(self.max_episode_steps, int) and self.max_episode_steps > 0,
            f"max_episode_steps must be a positive integer, got {self.max_episode_steps!r}",
        )
        _finite("accel_scale", self.accel_scale)
        _require(self.accel_scale > 0, "accel_scale must be positive")
        _require(
            isinstance(self.warmup_steps, int) and self.warmup_steps >= 0,
            "warmup_steps must be a non-negative integer",
        )
        _require(
            self.backend in SUMO_BACKENDS,
            f"unknown backend {self.backend!r}; choose one of {SUMO_BACKENDS}",
        )
        _require(
            isinstance(self.route_observation, bool),
            f"route_observation must be true or false, got {self.route_observation!r}",
        )
        _require(
            isinstance(self.window_observation, bool),
            f"window_observation must be true or false, got {self.window_observation!r}",
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON and YAML friendly); :meth:`from_dict` reads it back."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EnvConfig:
        """An :class:`EnvConfig` from nested plain data (a saved config, a JSON spec).

        ``scenario`` and ``grid`` are mappings of their fields; ranges may be lists.
        Unknown keys raise ``TypeError``, bad values ``ValueError``; a retired option
        (:data:`RETIRED_ENV_OPTIONS`) loads only at its off value.
        """
        data = without_retired(data, RETIRED_ENV_OPTIONS, "env")
        scenario = ScenarioConfig(**dict(data.pop("scenario", {})))
        grid_fields = dict(data.pop("grid", {}))
        for name in ("lateral_range", "longitudinal_range"):
            if name in grid_fields:
                grid_fields[name] = tuple(grid_fields[name])
        return cls(scenario=scenario, grid=GridConfig(**grid_fields), **data)
