"""Cached test results of the yardstick policies (frl.policies) on given test seeds.

A yardstick's result depends only on the test environment, the reward, the seeds and
the policy's own code, so it is computed once and kept under
``$FRL_CACHE_DIR/yardsticks`` (default ``~/.cache/frl/scenarios/yardsticks``), keyed by
a digest of all of them. Bump :data:`YARDSTICK_VERSION` when a yardstick changes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from frl.envs import EnvConfig, RewardConfig
from frl.envs.scenario import cache_root, scenario_key
from frl.fileio import read_json, write_json_atomic

YARDSTICK_VERSION = 1


def cache_dir() -> Path:
    return cache_root() / "yardsticks"


def cache_key(name: str, env: EnvConfig, reward: RewardConfig, seeds: Sequence[int]) -> str:
    """A digest of everything that decides a yardstick's test result."""
    env_fields = dataclasses.asdict(env)
    env_fields.pop("backend")  # libsumo and TraCI run the same simulation
    env_fields.pop("route_observation", None)  # the yardsticks read the grid alone
    env_fields.pop("window_observation", None)  # nor the windows beside it
    payload = {
        "version": YARDSTICK_VERSION,
        "policy": name,
        "scenario": scenario_key(env.scenario),  # covers the SUMO version too
        "env": env_fields,
        "reward": dataclasses.asdict(reward),
        "seeds": [int(seed) for seed in seeds],
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:24]


def load(key: str) -> dict[str, Any] | None:
    """The cached summary under ``key``, or None (a corrupt file counts as missing)."""
    path = cache_dir() / f"{key}.json"
    if not path.exists():
        return None
    try:
        return read_json(path)
    except (OSError, ValueError):
        return None


def store(key: str, summary: dict[str, Any]) -> None:
    cache_dir().mkdir(parents=True, exist_ok=True)
    write_json_atomic(cache_dir() / f"{key}.json", summary)
