"""What a run is, as typed library objects: the settings :func:`frl.train_config.validate`
builds from a composed config, and the federation builds its objects from
(:mod:`frl.federation.assembly`). Data only."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from frl.agents import DDPGConfig
from frl.envs import EnvConfig, RewardConfig
from frl.federation.plan import FederationPlan
from frl.federation.strategies import StrategySpec
from frl.retirement import RetiredOption

RETIRED_FEDERATION_OPTIONS: dict[str, RetiredOption] = {
    "round_arrival_period_factors": RetiredOption(
        None, '"Busy rounds, then the paper\'s traffic"', "8450bc8"
    ),
}
"""Federation options that frl retired (:mod:`frl.retirement`)."""


@dataclass(frozen=True)
class FlowerSettings:
    """``federation.backend=flower``: the runtime and the failure policy (docs/flower.md)."""

    runtime: str = "simulation"
    """simulation (one machine) | deployment (SuperLink + one SuperNode per vehicle)."""
    superlink: str | None = None
    """deployment: null starts a SuperLink and the SuperNodes on 127.0.0.1; "host:port"
    submits to a running SuperLink whose SuperNodes run python -m frl.flower.node."""
    accept_failures: bool = True
    """A vehicle that fails is dropped and the round goes on (fedavg only), as Flower's FedAvg."""
    min_clients: int = 2
    """Fewest vehicles that must answer for the run to go on (fedavg)."""
    connect_timeout_s: float = 300.0
    """Longest wait for every vehicle's SuperNode to connect."""


@dataclass(frozen=True)
class TrainSettings:
    """A validated configuration: what the run is (:func:`frl.train_config.validate`)."""

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
    cores: int | None = None
    """CPU cores of the run; None: every available core."""
    strategy: StrategySpec = field(default_factory=StrategySpec)
    vehicle_envs: tuple[EnvConfig, ...] | None = None
    """Each vehicle's training environment where the fleet's traffic differs; None: ``env``."""
    workers: int = 0
    stack_updates: bool = False
    """The vehicles a worker process hosts train in lockstep and learn in one stacked
    update (``federation.stack_updates`` resolved)."""
    round_test_episodes: int = 0
    """Test episodes per task after every round (the per-round test curve); 0: none."""
    collision_budget_by_task: Mapping[str, float] | None = None
    """Each task's vehicles' collision budget (``agent.collision_budget_by_task``); None:
    every vehicle has ``agent.collision_budget``."""
