"""``IntersectionEnv``: the paper's broken-traffic-light intersection as a gymnasium env."""

from __future__ import annotations

import copy
import dataclasses
import math
from array import array
from dataclasses import dataclass
from typing import Any, ClassVar, SupportsFloat

import gymnasium as gym
import numpy as np

from frl.envs.config import TASKS, EnvConfig, RewardConfig
from frl.envs.conflicts import WINDOW_FEATURES, CrossingReader
from frl.envs.observation import OccupancyGrid
from frl.envs.reward import RewardSignals, cost_terms, reward_terms
from frl.envs.scenario import Scenario, build_scenario
from frl.envs.sumo_backend import BRAKE_LIGHT_BIT, EGO_ID, SumoSimulation, VehicleState

_SEED_BOUND = 2**31 - 1
ROUTE_DISTANCE_SCALE_M = 10.0
"""The route observation's distance to the stop line is in units of this many metres."""


@dataclass(frozen=True)
class EnvSnapshot:
    """Everything :meth:`IntersectionEnv.restore` needs to put the env back exactly.

    SUMO's own ``saveState``/``loadState`` cannot do this mid-run: a reload restores
    each random generator by discarding its saved draw count from the *current* state,
    and loading the vehicles draws again from the generator that gives departing cars
    their random speed, so the traffic after a restore drifts from the traffic without
    one. A simulation is fully determined by its SUMO seed and the commands sent to it,
    so the snapshot keeps those and a restore replays them.
    """

    sumo_seed: int
    ego_speed_commands: tuple[float, ...]
    """Every speed set on the ego since SUMO started, one per simulation step."""
    ego_insertions: tuple[tuple[int, str], ...]
    """(number of speed commands before it, task) for each ego inserted since the start."""
    task: str
    steps: int
    done: bool
    rng_state: dict[str, Any]
    travelled: float = 0.0
    """Metres the ego has driven in this episode (the route observation's distance)."""

    def to_record(self) -> tuple[dict[str, Any], np.ndarray]:
        """JSON-ready fields and the speed commands (float64), for a file with no pickle."""
        fields = {
            "sumo_seed": self.sumo_seed,
            "ego_insertions": [[index, task] for index, task in self.ego_insertions],
            "task": self.task,
            "steps": self.steps,
            "done": self.done,
            "rng_state": self.rng_state,
            "travelled": self.travelled,  # a float's JSON text reads back to the same float
        }
        return fields, np.asarray(self.ego_speed_commands, np.float64)

    @classmethod
    def from_record(cls, fields: dict[str, Any], speed_commands: np.ndarray) -> EnvSnapshot:
        """The snapshot :meth:`to_record` wrote."""
        return cls(
            sumo_seed=int(fields["sumo_seed"]),
            ego_speed_commands=tuple(float(v) for v in np.asarray(speed_commands, np.float64)),
            ego_insertions=tuple((int(i), str(t)) for i, t in fields["ego_insertions"]),
            task=str(fields["task"]),
            steps=int(fields["steps"]),
            done=bool(fields["done"]),
            rng_state=fields["rng_state"],
            travelled=float(fields["travelled"]),
        )


class IntersectionEnv(gym.Env[Any, np.ndarray]):
    """An agent car crosses a four-way intersection with broken lights among aggressive humans.

    - Observation: the (26, 18, 3) float32 grid of Eq. (1) in the ego's frame
      (:class:`frl.envs.observation.OccupancyGrid`); with ``route_observation`` a Dict of
      that grid (``"grid"``) and the ego's route (``"route"``: the task one-hot and the
      distance to the stop line in tens of metres); with ``window_observation`` a
      ``"windows"`` part too, the grid's crossing cars as times
      (:meth:`frl.envs.conflicts.CrossingReader.features`).
    - Action: ``Box(-1, 1, (1,))``, an acceleration of ``action * accel_scale`` m/s^2.
      The ego's speed is set every step: v <- clip(v + a * dt, 0, speed_limit).
      Actions outside [-1, 1] are clipped; a non-finite action raises ``ValueError``.
    - Reward: :class:`frl.envs.config.RewardConfig`; ``info["reward_terms"]`` holds the
      weighted terms, which sum to the reward.
    - Termination: the ego collides (it is in SUMO's colliding-vehicle list) or arrives.
      Truncation: ``max_episode_steps`` steps without either.
    - ``info``: ``task``, ``collision``, ``arrived``, ``travel_time_steps`` (steps taken
      in this episode), ``reward_terms``, ``ego_speed``, and ``cost_terms`` with their sum
      ``cost`` (:data:`frl.envs.reward.COST_TERMS`, what a collision budget counts).

    One SUMO simulation runs across episodes: ``reset(seed=s)`` (re)starts it with
    SUMO seed ``s``; a plain ``reset()`` removes the old ego and inserts a new one into
    the traffic that kept flowing. The same seed and actions give the same episodes.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 5}

    def __init__(
        self,
        config: EnvConfig | None = None,
        reward: RewardConfig | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        """``overrides`` replace fields of ``config`` (for ``gymnasium.make`` kwargs)."""
        config = config if config is not None else EnvConfig()
        if overrides:
            config = dataclasses.replace(config, **overrides)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        if render_mode == "human" and config.backend != "traci":
            raise ValueError("render_mode='human' opens sumo-gui, which needs backend='traci'")
        self.config = config
        self.reward_config = reward if reward is not None else RewardConfig()
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": round(1 / config.scenario.step_length)}

        grid = config.grid
        speed_high = config.scenario.speed_limit / grid.speed_scale
        heading_high = 180.0 / grid.heading_scale_deg
        low = np.broadcast_to(np.array([0.0, -heading_high, 0.0], np.float32), grid.shape)
        high = np.broadcast_to(np.array([speed_high, heading_high, 1.0], np.float32), grid.shape)
        grid_space = gym.spaces.Box(low.copy(), high.copy(), dtype=np.float32)
        self.observation_space: gym.spaces.Box | gym.spaces.Dict = grid_space
        parts: dict[str, gym.spaces.Box] = {}
        if config.route_observation:
            start = config.scenario.ego_start_distance / ROUTE_DISTANCE_SCALE_M
            end = -config.scenario.arm_length / ROUTE_DISTANCE_SCALE_M
            parts["route"] = gym.spaces.Box(
                np.array([0.0, 0.0, 0.0, end], np.float32),
                np.array([1.0, 1.0, 1.0, start], np.float32),
                dtype=np.float32,
            )
        if config.window_observation:
            parts["windows"] = gym.spaces.Box(0.0, 1.0, (WINDOW_FEATURES,), dtype=np.float32)
        if parts:
            self.observation_space = gym.spaces.Dict({"grid": grid_space, **parts})
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

        self._scenario: Scenario | None = None
        self._simulation: SumoSimulation | None = None
        self._task = config.task if config.task != "random" else TASKS[0]
        self._steps = 0
        self._done = True
        self._ego_speed = 0.0
        self._travelled = 0.0
        self._vehicles: list[VehicleState] | None = None
        self._grid = OccupancyGrid(config.grid)
        self._crossings = CrossingReader(config) if config.window_observation else None
        # The commands since SUMO last started, for restore(): see EnvSnapshot.
        self._sumo_seed: int | None = None
        self._speed_commands = array("d")
        self._insertions: list[tuple[int, str]] = []

    @property
    def task(self) -> str:
        """The current episode's task (drawn at reset when the config says ``random``)."""
        return self._task

    @property
    def episode_steps(self) -> int:
        """Steps taken in the current episode (0 right after ``reset``)."""
        return self._steps

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Start an episode. ``options={"task": ...}`` overrides the task for this episode."""
        super().reset(seed=seed)
        task = (options or {}).get("task", self.config.task)
        if task == "random":
            task = TASKS[int(self.np_random.integers(len(TASKS)))]
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r}; choose one of {(*TASKS, 'random')}")
        simulation = self._ensure_simulation()
        if seed is not None or not simulation.is_running:
            self._start_simulation(int(self.np_random.integers(_SEED_BOUND)))
        self._task = task
        self._insert_ego(task)
        self._steps = 0
        self._travelled = 0.0
        self._done = False
        return self._observe_reset()

    def _start_simulation(self, sumo_seed: int) -> None:
        simulation = self._ensure_simulation()
        simulation.start(sumo_seed)
        for _ in range(self.config.warmup_steps):
            simulation.step()
        self._sumo_seed = sumo_seed
        self._speed_commands = array("d")
        self._insertions = []

    def _insert_ego(self, task: str) -> None:
        simulation = self._ensure_simulation()
        self._insertions.append((len(self._speed_commands), task))
        simulation.insert_ego(task)
        simulation.step()
        simulation.configure_ego()

    def _advance(self, speed: float) -> Any:
        """Set the ego's speed and run one simulation step; the step's events."""
        assert self._simulation is not None
        self._speed_commands.append(speed)
        self._simulation.set_ego_speed(speed)
        return self._simulation.step()

    def _observe_reset(self) -> tuple[Any, dict[str, Any]]:
        assert self._simulation is not None
        self._vehicles = self._simulation.vehicles()
        ego = _find_ego(self._vehicles)
        if ego is None:
            raise RuntimeError("SUMO did not insert the ego vehicle")
        self._ego_speed = ego.speed
        observation = self._observation(self._grid(self._vehicles, ego))
        return observation, self._info(collision=False, arrived=False, terms=None, costs=None)

    @property
    def stop_line_distance_m(self) -> float:
        """Metres from the ego to the stop line along its route (negative past it).

        The env always knows it, whatever the observation holds: a yardstick that reads
        it (``committed_gap_acceptance``) gets it here when the model under test sees the
        paper's grid alone."""
        return self.config.scenario.ego_start_distance - self._travelled

    def route(self) -> np.ndarray:
        """The ego's route now: the task one-hot and the distance to the stop line in units
        of :data:`ROUTE_DISTANCE_SCALE_M` (what ``route_observation`` adds to the grid)."""
        route = np.zeros(4, np.float32)
        route[TASKS.index(self._task)] = 1.0
        route[3] = self.stop_line_distance_m / ROUTE_DISTANCE_SCALE_M
        return route

    def _observation(self, grid: np.ndarray) -> Any:
        """The grid, or with ``route_observation`` or ``window_observation`` a Dict of
        the grid and the ego's route or the crossing cars' times."""
        if isinstance(self.observation_space, gym.spaces.Box):
            return grid
        observation = {"grid": grid}
        if self.config.route_observation:
            observation["route"] = self.route()
        if self._crossings is not None:
            observation["windows"] = self._crossings.features(grid)
        return observation

    def snapshot(self) -> EnvSnapshot:
        """The env's state now, for :meth:`restore` (a look-ahead, for instance).

        It holds every command since SUMO last started, and a restore replays them all,
        so both cost what the steps since the last seeded ``reset`` cost: use it on
        seeded episodes, as the test protocol does.
        """
        if self._sumo_seed is None or self._simulation is None:
            raise RuntimeError("snapshot() needs reset() first")
        return EnvSnapshot(
            sumo_seed=self._sumo_seed,
            ego_speed_commands=tuple(self._speed_commands),
            ego_insertions=tuple(self._insertions),
            task=self._task,
            steps=self._steps,
            done=self._done,
            rng_state=copy.deepcopy(self.np_random.bit_generator.state),
            travelled=self._travelled,
        )

    def restore(self, snapshot: EnvSnapshot) -> None:
        """Put the env and its simulation back to ``snapshot``, exactly.

        SUMO restarts with the snapshot's seed and replays the same commands, so the
        episode continues as if nothing had happened since the snapshot.
        """
        self._start_simulation(snapshot.sumo_seed)
        assert self._simulation is not None
        self._simulation.read_vehicles(False)
        insertions = iter(snapshot.ego_insertions)
        pending = next(insertions, None)
        for index, speed in enumerate(snapshot.ego_speed_commands):
            while pending is not None and pending[0] == index:
                self._insert_ego(pending[1])
                pending = next(insertions, None)
            self._advance(speed)
        while pending is not None:
            self._insert_ego(pending[1])
            pending = next(insertions, None)
        self._simulation.read_vehicles(True)
        self.np_random.bit_generator.state = copy.deepcopy(snapshot.rng_state)
        self._task = snapshot.task
        self._steps = snapshot.steps
        self._done = snapshot.done
        self._travelled = snapshot.travelled
        self._vehicles = self._simulation.vehicles()
        ego = _find_ego(self._vehicles)
        self._ego_speed = (
            ego.speed
            if ego is not None
            else (snapshot.ego_speed_commands[-1] if snapshot.ego_speed_commands else 0.0)
        )

    def step(self, action: np.ndarray) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self._done or self._simulation is None:
            raise RuntimeError("step() called before reset() or after the episode ended")
        acceleration = float(np.asarray(action, dtype=np.float64).reshape(-1)[0])
        if not math.isfinite(acceleration):
            raise ValueError(f"action must be finite, got {action!r}")
        acceleration = min(max(acceleration, -1.0), 1.0) * self.config.accel_scale
        scenario = self.config.scenario
        speed = self._ego_speed + acceleration * scenario.step_length
        speed = min(max(speed, 0.0), scenario.speed_limit)
        events = self._advance(speed)
        self._steps += 1
        self._vehicles = vehicles = self._simulation.vehicles()
        ego = _find_ego(vehicles)

        collision = events.ego_collided
        arrived = events.ego_arrived and not collision
        if ego is not None:
            self._ego_speed = ego.speed
            self._travelled += ego.speed * scenario.step_length  # SUMO's Euler update
            grid = self._grid(vehicles, ego)
            braking, waiting = self._disturbance(vehicles, ego)
        else:  # arrived: SUMO removed the ego during the step
            self._ego_speed = speed
            self._travelled += speed * scenario.step_length
            grid = np.zeros(self.config.grid.shape, np.float32)
            braking = waiting = False
        observation = self._observation(grid)
        signals = RewardSignals(
            moving=self._ego_speed > self.reward_config.moving_speed,
            others_braking=braking,
            others_waiting=waiting,
            collision=collision,
            arrived=arrived,
        )
        terms = reward_terms(signals, self.reward_config)
        reward = float(sum(terms.values()))
        costs = cost_terms(signals, self.reward_config)
        terminated = collision or arrived or ego is None
        truncated = not terminated and self._steps >= self.config.max_episode_steps
        self._done = terminated or truncated
        info = self._info(collision, arrived, terms, costs)
        return observation, reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None  # "human": sumo-gui draws itself
        from frl.envs.render import draw_intersection

        vehicles = self._vehicles
        if vehicles is None:
            raise RuntimeError("render() needs reset() first")
        return draw_intersection(vehicles, self.config.scenario, EGO_ID)

    def close(self) -> None:
        if self._simulation is not None:
            self._simulation.close()
            self._simulation = None
        self._done = True

    def _ensure_simulation(self) -> SumoSimulation:
        if self._scenario is None:
            self._scenario = build_scenario(self.config.scenario)
        if self._simulation is None:
            self._simulation = SumoSimulation(
                self._scenario,
                self.config.scenario,
                backend=self.config.backend,
                gui=self.render_mode == "human",
            )
        return self._simulation

    def _disturbance(self, vehicles: list[VehicleState], ego: VehicleState) -> tuple[bool, bool]:
        """Whether humans near the ego brake (brake-light bit) or wait (see RewardConfig)."""
        radius_sq = self.reward_config.disturbance_radius**2
        moving_speed = self.reward_config.moving_speed
        braking = waiting = False
        for vehicle_id, x, y, _, speed, signals in vehicles:
            dx, dy = x - ego.x, y - ego.y
            if vehicle_id != EGO_ID and dx * dx + dy * dy <= radius_sq:
                braking = braking or bool(signals & BRAKE_LIGHT_BIT)
                waiting = waiting or speed <= moving_speed
        return braking, waiting

    def _info(
        self, collision: bool, arrived: bool, terms: dict[str, float] | None,
        costs: dict[str, float] | None,
    ) -> dict[str, Any]:  # fmt: skip
        return {
            "task": self._task,
            "collision": collision,
            "cost": float(sum(costs.values())) if costs is not None else 0.0,
            "cost_terms": costs if costs is not None else {},
            "arrived": arrived,
            "travel_time_steps": self._steps,
            "ego_speed": self._ego_speed,
            "reward_terms": terms if terms is not None else {},
        }


def _find_ego(vehicles: list[VehicleState]) -> VehicleState | None:
    return next((vehicle for vehicle in vehicles if vehicle.id == EGO_ID), None)
