"""A top-down picture of the intersection: roads, the agent in red, humans in yellow."""

from __future__ import annotations

import numpy as np

from frl.envs.config import ScenarioConfig
from frl.envs.sumo_backend import VehicleState

_BACKGROUND = (46, 125, 50)
_ROAD = (70, 70, 70)
_MARKING = (235, 235, 235)
_AGENT = (220, 30, 30)
_HUMAN = (250, 210, 20)


def draw_intersection(
    vehicles: list[VehicleState],
    scenario: ScenarioConfig,
    ego_id: str,
    size: int = 480,
    view_radius: float = 60.0,
) -> np.ndarray:
    """An (size, size, 3) uint8 image of the square of ``view_radius`` m around the centre."""
    from PIL import Image, ImageDraw  # only needed when rendering

    scale = size / (2.0 * view_radius)

    def to_pixels(points: np.ndarray) -> list[tuple[float, float]]:
        # SUMO's y axis points north; image rows grow downwards.
        return [((x + view_radius) * scale, (view_radius - y) * scale) for x, y in points]

    image = Image.new("RGB", (size, size), _BACKGROUND)
    draw = ImageDraw.Draw(image)
    half = scenario.lane_width
    far = view_radius
    for corners in (
        [(-far, -half), (far, -half), (far, half), (-far, half)],
        [(-half, -far), (half, -far), (half, far), (-half, far)],
    ):
        draw.polygon(to_pixels(np.array(corners)), fill=_ROAD)
    for start, end in (((-far, 0), (-half, 0)), ((half, 0), (far, 0))):
        draw.line(to_pixels(np.array([start, end])), fill=_MARKING, width=1)
    for start, end in (((0, -far), (0, -half)), ((0, half), (0, far))):
        draw.line(to_pixels(np.array([start, end])), fill=_MARKING, width=1)

    for vehicle in vehicles:
        outline = _vehicle_outline(
            np.array([vehicle.x, vehicle.y]),
            vehicle.angle,
            scenario.vehicle_length,
            scenario.vehicle_width,
        )
        color = _AGENT if vehicle.id == ego_id else _HUMAN
        draw.polygon(to_pixels(outline), fill=color, outline=(0, 0, 0))
    return np.asarray(image, dtype=np.uint8)


def _vehicle_outline(
    front: np.ndarray, angle_deg: float, length: float, width: float
) -> np.ndarray:
    """The four corners of a vehicle whose front bumper centre is ``front``."""
    heading = np.deg2rad(angle_deg)
    forward = np.array([np.sin(heading), np.cos(heading)])
    right = np.array([np.cos(heading), -np.sin(heading)])
    back = front - forward * length
    half = right * (width / 2.0)
    return np.array([front - half, front + half, back + half, back - half])
