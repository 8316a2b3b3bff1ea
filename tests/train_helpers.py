"""Tiny training configs for the federation and train tests (not a test module)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from hydra import compose, initialize_config_dir

from frl.agents import DDPGConfig
from frl.envs import EnvConfig, RewardConfig
from frl.federation import ClientSpec
from frl.train_config import register_configs

CONF_DIR = str(Path(__file__).resolve().parents[1] / "frl" / "conf")
SCRIPTS_DIR = Path(__file__).resolve().parents[1] / "scripts"

TINY_OVERRIDES = [
    "total_steps=240",
    "interval=40",
    "agent.hidden_sizes=[16,16]",
    "agent.batch_size=16",
    "agent.learning_starts=40",
    "agent.train_freq=2",
    "agent.buffer_size=1000",
    "env.max_episode_steps=50",
    "env.warmup_steps=10",
    "eval_episodes=2",
    "progress=false",
]
"""3 rounds of 40 updates (80 steps) per client, episodes of at most 50 steps: every client crosses
at least one episode end and two aggregations. An update every second step (100 a
client) halves the time the tiny runs spend in updates, the most of their training."""

TINY_AGENT = DDPGConfig(hidden_sizes=(16, 16), batch_size=16, learning_starts=20, buffer_size=500)
TINY_ENV = EnvConfig(max_episode_steps=30, warmup_steps=10)


def compose_config(run_dir: Path | None, overrides: list[str] = (), tiny: bool = True):  # type: ignore[assignment]
    """The composed Hydra config with the tiny overrides (without them, with ``tiny=False``:
    as ``python -m frl.train`` composes it), writing into ``run_dir``."""
    register_configs()
    extra = [f"run_dir={run_dir}"] if run_dir is not None else []
    base = TINY_OVERRIDES if tiny else []
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose("config", overrides=[*base, *extra, *overrides])


def tiny_spec(index: int, task: str, seed: int = 0) -> ClientSpec:
    return ClientSpec(
        index=index,
        task=task,
        env=TINY_ENV,
        reward=RewardConfig(),
        agent=TINY_AGENT,
        agent_seed=seed + index,
        env_seed=2 * (seed + index),
    )


def load_script(name: str) -> ModuleType:
    """``scripts/NAME.py`` as a module (the scripts are no package), registered in
    ``sys.modules`` as dataclasses need to look their module up."""
    spec = importlib.util.spec_from_file_location(name, SCRIPTS_DIR / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
