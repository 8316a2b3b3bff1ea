"""The one module of frl that talks to SUMO, through libsumo or socket TraCI.

libsumo runs SUMO inside this process and is about 70x faster than TraCI over a
socket, but it holds one simulation per process and silently replaces a running one
when started again. :class:`SumoSimulation` therefore refuses to open a second
libsumo simulation while one is open. TraCI, needed for sumo-gui, has no such limit.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from frl.envs.config import ScenarioConfig
from frl.envs.scenario import AGENT_TYPE, JUNCTION_ID, Scenario, sumo_binary

EGO_ID = "ego"
HUMAN_SPEED_MODE = 39
"""Safe following and accel/decel limits kept; right of way and junction foes ignored."""
EGO_SPEED_MODE = 0
"""All checks off: the ego's speed is exactly what the policy sets."""
BRAKE_LIGHT_BIT = 8
"""TraCI's VEH_SIGNAL_BRAKELIGHT bit of ``vehicle.getSignals``."""

# TraCI variable ids (traci.constants); spelled out to keep this module's import light.
_VAR_SPEED = 0x40
_VAR_POSITION = 0x42
_VAR_ANGLE = 0x43
_VAR_SIGNALS = 0x5B
_CMD_GET_VEHICLE_VARIABLE = 0xA4
_SUBSCRIBED = (_VAR_POSITION, _VAR_ANGLE, _VAR_SPEED, _VAR_SIGNALS)
_VAR_DEPARTED_IDS = 0x74
_VAR_ARRIVED_IDS = 0x7A
_VAR_COLLIDING_IDS = 0x81
_STEP_EVENTS = (_VAR_DEPARTED_IDS, _VAR_COLLIDING_IDS, _VAR_ARRIVED_IDS)
"""A step's events come back with the step itself: over TraCI three fewer round trips a
step, which is most of what a restore's replay costs."""

_libsumo_owner: SumoSimulation | None = None
_new_tuple = tuple.__new__
_traci_labels = itertools.count()


class SumoError(RuntimeError):
    """SUMO failed or was used in a way it does not support."""


class VehicleState(NamedTuple):
    """One vehicle after a step, as read from the context subscription."""

    id: str
    x: float
    """Front-bumper x (m, east)."""
    y: float
    """Front-bumper y (m, north)."""
    angle: float
    """SUMO heading: degrees clockwise from north."""
    speed: float
    """m/s."""
    signals: int
    """TraCI signal bit set (brake lights: ``signals & BRAKE_LIGHT_BIT``)."""


@dataclass
class StepEvents:
    """What happened to the ego during one simulation step."""

    ego_collided: bool
    ego_arrived: bool
    departed: tuple[str, ...] = ()
    """Vehicles that entered the network during the step (the ego included)."""


def sumo_command(
    scenario: Scenario, config: ScenarioConfig, seed: int, gui: bool = False
) -> list[str]:
    """The SUMO command line: options follow SUMO's Simulation/Safety documentation."""
    return [
        sumo_binary("sumo-gui" if gui else "sumo"),
        "--net-file", str(scenario.net_file),
        "--route-files", str(scenario.route_file),
        "--step-length", f"{config.step_length:.10g}",
        "--seed", str(seed),
        # Collisions inside the junction are detected only with this option.
        "--collision.check-junctions", "true",
        # Report collisions and keep the vehicles; the default teleports them away.
        "--collision.action", "warn",
        # Count physical overlaps only, not a follower closer than its minGap.
        "--collision.mingap-factor", "0",
        # Never teleport jammed vehicles: a teleport must not look like a collision.
        "--time-to-teleport", "-1",
        "--no-step-log", "true",
        "--no-warnings", "true",
        "--duration-log.disable", "true",
        *(["--start", "true", "--quit-on-end", "true"] if gui else []),
    ]  # fmt: skip


_TRACI_CONNECT_WAIT_S = 0.02
_TRACI_CONNECT_TIMEOUT_S = 60.0
PORT_LOCK_FILE = Path(tempfile.gettempdir()) / "frl-traci-port.lock"
"""The machine-wide lock held while a free port is picked and SUMO takes it."""


@contextlib.contextmanager
def one_port_pick_at_a_time(lock_file: Path = PORT_LOCK_FILE) -> Iterator[None]:
    """Hold a lock across processes while a free port is picked and SUMO takes it. A port
    found free stays free until SUMO binds it, so two processes starting SUMO at once can
    be handed the same one: one SUMO then quits and its client talks to the other's SUMO
    (seen with 99 vehicles in 16 processes: "Connection closed by SUMO")."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock
        yield
        return
    # Read-only, so that any user may lock a file another user's run created.
    descriptor = os.open(lock_file, os.O_RDONLY | os.O_CREAT, 0o666)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX)
        yield
    finally:
        os.close(descriptor)  # closing releases the lock


def _start_traci(command: list[str], label: str) -> Any:
    """``traci.start``, without its one-second wait before SUMO's first answer: start SUMO
    on a free port and connect as soon as it listens. A restore over TraCI pays a start."""
    import io
    import subprocess

    import traci

    for _ in range(3):  # another program may take the free port first, as traci.start allows
        with one_port_pick_at_a_time():
            port = traci.getFreeSocketPort()
            process = subprocess.Popen([*command, "--remote-port", str(port)])
            try:
                with contextlib.redirect_stdout(io.StringIO()):  # traci prints every retry
                    traci.connect(
                        port,
                        numRetries=int(_TRACI_CONNECT_TIMEOUT_S / _TRACI_CONNECT_WAIT_S),
                        proc=process,
                        waitBetweenRetries=_TRACI_CONNECT_WAIT_S,
                        label=label,
                    )
            except traci.TraCIException:  # SUMO exited: the port was taken
                continue
        return traci.getConnection(label)
    raise SumoError(f"SUMO did not accept a TraCI connection: {' '.join(command)}")


def _hold_back() -> None:
    """In place of traci's ``Connection._sendExact``: leave the command queued."""


class SumoSimulation:
    """A running SUMO of the intersection: start, step, read vehicles, steer the ego."""

    def __init__(self, scenario: Scenario, config: ScenarioConfig, backend: str, gui: bool):
        if gui and backend != "traci":
            raise ValueError("sumo-gui needs backend='traci' (libsumo has no GUI)")
        self._scenario = scenario
        self._config = config
        self._backend = backend
        self._gui = gui
        self._api: Any = None  # the libsumo module or a traci.Connection
        self._label: str | None = None
        self._context_radius = 2.0 * config.arm_length

    @property
    def is_running(self) -> bool:
        return self._api is not None

    def start(self, seed: int) -> None:
        """Start SUMO with ``seed``, or reload the running one with it."""
        global _libsumo_owner
        command = sumo_command(self._scenario, self._config, seed, self._gui)
        if self._api is not None:
            self._guard(lambda: self._api.load(command[1:]))
        elif self._backend == "libsumo":
            if _libsumo_owner is not None:
                raise SumoError(
                    "libsumo allows one simulation per process and another IntersectionEnv "
                    "already has it open. close() that env first, create envs in separate "
                    "processes, or pass backend='traci'."
                )
            import libsumo

            self._guard(lambda: libsumo.start(command))
            self._api = libsumo
            _libsumo_owner = self
        else:
            label = f"frl-{os.getpid()}-{next(_traci_labels)}"
            self._api = self._guard(lambda: _start_traci(command, label))
            self._label = label
        self._guard(self._subscribe)

    def _subscribe(self) -> None:
        self.read_vehicles(True)
        self._api.simulation.subscribe(_STEP_EVENTS)

    def read_vehicles(self, on: bool) -> None:
        """Whether each step brings the vehicles near the junction (:meth:`vehicles`).

        Off while a restore replays steps nobody looks at: over TraCI the readings are
        most of a step's reply. Turned on, they are read at once for the current step.
        """
        junction = self._api.junction
        if on:
            junction.subscribeContext(
                JUNCTION_ID, _CMD_GET_VEHICLE_VARIABLE, self._context_radius, _SUBSCRIBED
            )
        else:
            junction.unsubscribeContext(
                JUNCTION_ID, _CMD_GET_VEHICLE_VARIABLE, self._context_radius
            )

    def step(self) -> StepEvents:
        """Advance one step; give new humans their speed mode; report the ego's events."""
        api = self._api
        # simulation.step skips the Python step-listener bookkeeping of simulationStep.
        simulation = api.simulation
        self._guard(simulation.step)
        events = simulation.getSubscriptionResults()
        departed = tuple(events[_VAR_DEPARTED_IDS])
        with self._sent_with_next_command():
            for vehicle_id in departed:
                if vehicle_id != EGO_ID:
                    api.vehicle.setSpeedMode(vehicle_id, HUMAN_SPEED_MODE)
        return StepEvents(
            ego_collided=EGO_ID in events[_VAR_COLLIDING_IDS],
            ego_arrived=EGO_ID in events[_VAR_ARRIVED_IDS],
            departed=departed,
        )

    def vehicles(self) -> list[VehicleState]:
        """All vehicles near the junction, read from one context subscription."""
        results = self._api.junction.getContextSubscriptionResults(JUNCTION_ID) or {}
        # tuple.__new__ skips the NamedTuple constructor's Python-level argument handling.
        return [
            _new_tuple(
                VehicleState,
                (
                    vehicle_id,
                    *values[_VAR_POSITION],
                    values[_VAR_ANGLE],
                    values[_VAR_SPEED],
                    values[_VAR_SIGNALS],
                ),
            )
            for vehicle_id, values in results.items()
        ]

    def insert_ego(self, task: str) -> None:
        """Remove any previous ego, then add one for ``task`` at rest before the stop line.

        SUMO inserts it on the next step, after which its speed mode can be set.
        """
        vehicle = self._api.vehicle
        if EGO_ID in vehicle.getIDList():
            vehicle.remove(EGO_ID)
        self._guard(
            lambda: vehicle.add(
                EGO_ID,
                f"ego_{task}",
                typeID=AGENT_TYPE,
                depart="now",
                departLane="first",
                departPos=f"{self._scenario.ego_depart_pos:.6f}",
                departSpeed="0",
                arrivalPos=f"{self._scenario.ego_arrival_pos[task]:.6f}",
            )
        )

    def configure_ego(self) -> None:
        """Hand the ego's speed to the policy (speed mode 0) once it is in the network."""
        self._api.vehicle.setSpeedMode(EGO_ID, EGO_SPEED_MODE)

    def set_ego_speed(self, speed: float) -> None:
        with self._sent_with_next_command():
            self._api.vehicle.setSpeed(EGO_ID, speed)

    @contextlib.contextmanager
    def _sent_with_next_command(self) -> Iterator[None]:
        """Over TraCI, the set commands issued inside travel with the next command, in one
        message: the protocol takes many commands a message, but traci's client sends each
        alone and waits for its answer. A step and the commands before it are then one
        round trip, the same commands in the same order. Set commands only: their answer
        is a bare status, which traci reads in turn when the message goes out, so an error
        in one surfaces at the next command."""
        connection = self._api
        if self._backend != "traci":
            yield
            return
        connection._sendExact = _hold_back  # an instance attribute shadows the method
        try:
            yield
        finally:
            del connection._sendExact

    def close(self) -> None:
        """Stop SUMO. Safe to call any number of times."""
        global _libsumo_owner
        api, self._api = self._api, None
        if api is None:
            return
        try:
            api.close()
        except Exception:  # SUMO may already be gone; closing must not fail
            pass
        finally:
            if _libsumo_owner is self:
                _libsumo_owner = None

    def _guard(self, call: Any) -> Any:
        try:
            return call()
        except Exception as error:  # libsumo raises its own TraCIException types
            if isinstance(error, SumoError):
                raise
            raise SumoError(f"SUMO ({self._backend}) failed: {error}") from error
