"""Generate the intersection's SUMO network and routes once, and cache them by config.

The network is a four-way crossing of single-lane, two-way roads, with no traffic
lights and a junction of type ``priority`` (on ``unregulated`` junctions SUMO never
registers collisions inside the junction; see SUMO's Simulation/Safety page). The
east-west road is the major road. Humans cross it in both directions; the ego
arrives from the south and turns left, goes straight or turns right.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from frl.envs.config import TASKS, ScenarioConfig

JUNCTION_ID = "C"
APPROACH_EDGE = "S2C"
EGO_ROUTES: dict[str, tuple[str, str]] = {
    "left": (APPROACH_EDGE, "C2W"),
    "straight": (APPROACH_EDGE, "C2N"),
    "right": (APPROACH_EDGE, "C2E"),
}
HUMAN_ROUTES: dict[str, tuple[str, str]] = {
    "human_we": ("W2C", "C2E"),
    "human_ew": ("E2C", "C2W"),
}
AGENT_TYPE = "agent"
HUMAN_TYPE = "human"
_FORMAT_VERSION = 1
_META_FILE = "scenario.json"


@dataclass(frozen=True)
class Scenario:
    """Paths to the generated SUMO files and the positions derived from the network."""

    directory: Path
    net_file: Path
    route_file: Path
    ego_depart_pos: float
    """Position (m along the approach edge) of the ego's front bumper at departure."""
    ego_arrival_pos: dict[str, float]
    """Per task, the position on the exit edge where the ego arrives."""
    junction_offset: float
    """Distance (m) from the junction centre to where each arm's edge begins."""


def sumo_home() -> Path:
    """The SUMO installation inside the ``eclipse-sumo`` wheel."""
    import sumo  # the eclipse-sumo wheel; imported here so frl imports without it

    return Path(sumo.SUMO_HOME)


def sumo_binary(name: str) -> str:
    """Path of a SUMO executable (``sumo``, ``sumo-gui``, ``netconvert``) from the wheel."""
    path = sumo_home() / "bin" / name
    if not path.exists():
        raise FileNotFoundError(f"{name} not found in the eclipse-sumo wheel at {path}")
    return str(path)


def sumo_version() -> str:
    from importlib.metadata import version

    return version("eclipse-sumo")


def cache_root() -> Path:
    """Where generated scenarios live: ``$FRL_CACHE_DIR`` or ``~/.cache/frl/scenarios``."""
    configured = os.environ.get("FRL_CACHE_DIR")
    if configured:
        return Path(configured)
    xdg = os.environ.get("XDG_CACHE_HOME", str(Path.home() / ".cache"))
    return Path(xdg) / "frl" / "scenarios"


def scenario_key(config: ScenarioConfig) -> str:
    """A stable digest of everything that shapes the generated files."""
    payload = {
        "format": _FORMAT_VERSION,
        "sumo": sumo_version(),
        "config": dataclasses.asdict(config),
    }
    text = json.dumps(payload, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def build_scenario(config: ScenarioConfig, root: Path | None = None) -> Scenario:
    """Return the cached scenario for ``config``, generating it with netconvert if needed.

    Generation happens in a temporary directory that is renamed into place, so a
    crash or a concurrent process never leaves a half-written scenario in the cache.
    """
    root = cache_root() if root is None else root
    target = root / scenario_key(config)
    if not (target / _META_FILE).exists():
        root.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".tmp-", dir=root))
        try:
            _generate(config, staging)
            try:
                staging.rename(target)
            except OSError:
                # Another process won the race; its copy is identical.
                if not (target / _META_FILE).exists():
                    raise
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    return _load(target)


def _load(directory: Path) -> Scenario:
    meta = json.loads((directory / _META_FILE).read_text())
    return Scenario(
        directory=directory,
        net_file=directory / "intersection.net.xml",
        route_file=directory / "intersection.rou.xml",
        ego_depart_pos=meta["ego_depart_pos"],
        ego_arrival_pos=meta["ego_arrival_pos"],
        junction_offset=meta["junction_offset"],
    )


def _generate(config: ScenarioConfig, directory: Path) -> None:
    nodes = directory / "intersection.nod.xml"
    edges = directory / "intersection.edg.xml"
    net = directory / "intersection.net.xml"
    nodes.write_text(_nodes_xml(config))
    edges.write_text(_edges_xml(config))
    command = [
        sumo_binary("netconvert"),
        "--node-files", str(nodes),
        "--edge-files", str(edges),
        "--output-file", str(net),
        "--no-turnarounds", "true",
        # Keep the junction centre at the origin: the renderer and docs rely on it.
        "--offset.disable-normalization", "true",
        "--default.lanewidth", str(config.lane_width),
        "--no-warnings", "true",
    ]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"netconvert failed ({result.returncode}):\n{result.stderr}")

    approach_length, exit_lengths = _edge_lengths(net)
    junction_offset = config.arm_length - approach_length
    ego_depart_pos = approach_length - config.ego_start_distance
    ego_arrival_pos = {
        task: config.ego_destination_distance - (config.arm_length - exit_lengths[exit_edge])
        for task, (_, exit_edge) in EGO_ROUTES.items()
    }
    for task, pos in ego_arrival_pos.items():
        if not 0 < pos < exit_lengths[EGO_ROUTES[task][1]]:
            raise ValueError(
                f"ego_destination_distance={config.ego_destination_distance} puts the "
                f"{task} destination outside its exit edge"
            )
    (directory / "intersection.rou.xml").write_text(_routes_xml(config))
    meta = {
        "ego_depart_pos": ego_depart_pos,
        "ego_arrival_pos": ego_arrival_pos,
        "junction_offset": junction_offset,
        "config": dataclasses.asdict(config),
    }
    (directory / _META_FILE).write_text(json.dumps(meta, indent=2))


def _edge_lengths(net_file: Path) -> tuple[float, dict[str, float]]:
    import sumolib  # only needed while generating

    net = sumolib.net.readNet(str(net_file))
    approach = net.getEdge(APPROACH_EDGE).getLength()
    exits = {edge: net.getEdge(edge).getLength() for _, edge in EGO_ROUTES.values()}
    return approach, exits


def _nodes_xml(config: ScenarioConfig) -> str:
    length = config.arm_length
    ends = {"N": (0.0, length), "S": (0.0, -length), "E": (length, 0.0), "W": (-length, 0.0)}
    lines = [f'    <node id="{JUNCTION_ID}" x="0" y="0" type="priority"/>']
    lines += [f'    <node id="{n}" x="{x}" y="{y}" type="dead_end"/>' for n, (x, y) in ends.items()]
    return "<nodes>\n" + "\n".join(lines) + "\n</nodes>\n"


def _edges_xml(config: ScenarioConfig) -> str:
    # The east-west road is the major road (priority 2): humans cross on it.
    priority = {"E": 2, "W": 2, "N": 1, "S": 1}
    lines = []
    for arm in ("N", "S", "E", "W"):
        for src, dst in ((arm, JUNCTION_ID), (JUNCTION_ID, arm)):
            lines.append(
                f'    <edge id="{src}2{dst}" from="{src}" to="{dst}" numLanes="1" '
                f'speed="{config.speed_limit}" priority="{priority[arm]}"/>'
            )
    return "<edges>\n" + "\n".join(lines) + "\n</edges>\n"


def _routes_xml(config: ScenarioConfig) -> str:
    period = config.human_period_seconds
    if config.human_arrival_process == "bernoulli":
        # SUMO draws a departure every step and scales this per-second probability to
        # the step length (Simulation/Randomness): the lineage's probability="0.1".
        depart_attr = f'probability="{1.0 / period:.10g}"'
    elif config.human_arrival_process == "poisson":
        # SUMO's exp(rate): exponentially distributed headways, rate per second.
        depart_attr = f'period="exp({1.0 / period:.10g})"'
    else:
        depart_attr = f'period="{period:.10g}"'
    size = f'length="{config.vehicle_length}" width="{config.vehicle_width}"'
    lines = [
        # Table I: both types have max speed 20.1168; speed modes are set via TraCI
        # (agent 0, human 39) because SUMO has no vType attribute for them.
        f'    <vType id="{AGENT_TYPE}" color="red" maxSpeed="{config.speed_limit}" '
        f'{size} speedFactor="1" speedDev="0"/>',
        f'    <vType id="{HUMAN_TYPE}" color="yellow" maxSpeed="{config.speed_limit}" '
        f'{size} speedFactor="1" speedDev="{config.human_speed_dev:.10g}"/>',
    ]
    for task, edges in EGO_ROUTES.items():
        lines.append(f'    <route id="ego_{task}" edges="{" ".join(edges)}"/>')
    for route_id, edges in HUMAN_ROUTES.items():
        lines.append(f'    <route id="{route_id}" edges="{" ".join(edges)}"/>')
    for route_id in HUMAN_ROUTES:
        lines.append(
            f'    <flow id="{route_id}" type="{HUMAN_TYPE}" route="{route_id}" begin="0" '
            f'end="1e9" {depart_attr} departSpeed="random" departLane="first"/>'
        )
    return "<routes>\n" + "\n".join(lines) + "\n</routes>\n"


assert set(EGO_ROUTES) == set(TASKS)
