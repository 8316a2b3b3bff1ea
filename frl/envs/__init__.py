"""The intersection scenario: SUMO network generation and the gymnasium environment.

Importing this package registers ``frl/Intersection-v0`` with gymnasium; it starts no
SUMO and writes no files.
"""

import gymnasium as gym

from frl.envs.config import (
    TASK_CHOICES,
    TASKS,
    TRAFFIC_PRESETS,
    EnvConfig,
    GridConfig,
    RewardConfig,
    ScenarioConfig,
    traffic_name,
    traffic_preset,
)
from frl.envs.intersection import EnvSnapshot, IntersectionEnv
from frl.envs.sumo_backend import SumoError

ENV_ID = "frl/Intersection-v0"

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="frl.envs.intersection:IntersectionEnv")

__all__ = [
    "ENV_ID",
    "TASKS",
    "TASK_CHOICES",
    "TRAFFIC_PRESETS",
    "EnvConfig",
    "EnvSnapshot",
    "GridConfig",
    "IntersectionEnv",
    "RewardConfig",
    "ScenarioConfig",
    "SumoError",
    "traffic_name",
    "traffic_preset",
]
