"""The three training schemes of Section IV.B, their round structure and their seeds."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from frl.envs import TASKS
from frl.federation.averaging import TARGET_MODES, WEIGHTINGS

SCHEMES: tuple[str, ...] = ("central", "separate", "fedavg")
"""``central``: Central-DDPG, one agent, a random task per episode. ``separate``:
Sep-DDPG, one agent per task, never averaged. ``fedavg``: FedAvg-DDPG, one agent per
task, averaged into one global model every ``interval`` steps."""
INITIAL_MODELS: tuple[str, ...] = ("shared", "independent")
"""How the clients' networks start: from one initial global model, or each its own."""

FEDERATION_BACKENDS: tuple[str, ...] = ("processes", "flower")
"""How clients run: ``processes`` = one spawned worker process per client (libsumo
allows one SUMO per process); ``flower`` = the vehicles as Flower ClientApps and the
roadside unit as a ServerApp (``pip install frl[flower]``; :mod:`frl.flower`)."""

FLOWER_RUNTIMES: tuple[str, ...] = ("simulation", "deployment")
"""``simulation``: Flower's simulation runtime on this machine. ``deployment``: a
SuperLink and one SuperNode per vehicle, separate processes talking over the network."""

_SEED_HALF_RANGE = 2**30


@dataclass(frozen=True)
class FederationPlan:
    """Which clients train, for how long, and how rounds and aggregation go.

    Every scheme runs in rounds of ``interval`` environment steps per client (the last
    round may be shorter), so logging and checkpoints have the same cadence; only
    ``fedavg`` averages at the end of a round.
    """

    scheme: str = "fedavg"
    tasks: tuple[str, ...] = TASKS
    """Vehicle tasks of ``separate``/``fedavg`` (a task may repeat: one vehicle per entry),
    the tasks ``central`` draws from; every scheme is tested on each distinct task."""
    vehicles_per_task: int = 1
    """The fleet is ``tasks`` repeated this many times, interleaved (left, straight,
    right, left, ...), so vehicle i is the same in every fleet that has it. ``central``
    stays one agent."""
    total_steps: int = 10_000
    """Environment steps per agent (the paper's budget: 10,000)."""
    interval: int = 2_000
    """Environment steps per client between two aggregations (the paper's best: 2,000)."""
    targets: str = "average"
    """``average``: target networks are averaged like the online ones. ``resync``: only
    online networks are uploaded and averaged; each client then copies online -> target."""
    weighting: str = "equal"
    """``equal``: Eq. (3). ``steps``: clients weighted by their steps in the round."""
    fraction_train: float = 1.0
    """Share of the fleet drawn to train each round, as Flower's ``fraction_train``:
    max(1, floor(fraction x vehicles)) vehicles; the others keep their state."""
    vehicles_per_round: int | None = None
    """Vehicles drawn each round, instead of ``fraction_train`` (None: use the fraction)."""
    initial_model: str | None = None
    """``shared``: every client's networks start from one initial model drawn from the run
    seed, as FedAvg's clients start from the server's initial global model. ``independent``:
    each client initialises its own from its agent seed. None: ``shared`` for ``fedavg``,
    ``independent`` for the other schemes."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "tasks", tuple(self.tasks))
        if self.scheme not in SCHEMES:
            raise ValueError(
                f"unknown federation scheme {self.scheme!r}; choose one of {', '.join(SCHEMES)}"
            )
        if not self.tasks:
            raise ValueError("federation.tasks must name at least one task")
        for task in self.tasks:
            if task not in TASKS:
                raise ValueError(
                    f"unknown task {task!r} in federation.tasks; choose from {', '.join(TASKS)}"
                )
        if not _is_int(self.vehicles_per_task) or self.vehicles_per_task < 1:
            raise ValueError(
                f"federation.vehicles_per_task must be a positive integer, "
                f"got {self.vehicles_per_task!r}"
            )
        fraction = self.fraction_train
        if (
            isinstance(fraction, bool)
            or not isinstance(fraction, (int, float))
            or not (0 < fraction <= 1)
        ):
            raise ValueError(f"federation.fraction_train must be in (0, 1], got {fraction!r}")
        per_round = self.vehicles_per_round
        if per_round is not None:
            if not _is_int(per_round) or per_round < 1:
                raise ValueError(
                    f"federation.vehicles_per_round must be a positive integer, got {per_round!r}"
                )
            if fraction != 1:
                raise ValueError(
                    "set federation.fraction_train or federation.vehicles_per_round, not both"
                )
            if per_round > self.fleet_size:
                raise ValueError(
                    f"federation.vehicles_per_round={per_round} exceeds the fleet's "
                    f"{self.fleet_size} vehicle{'s' * (self.fleet_size > 1)}"
                )
        if not _is_int(self.total_steps) or self.total_steps <= 0:
            raise ValueError(f"total_steps must be a positive integer, got {self.total_steps!r}")
        if not _is_int(self.interval) or not 0 < self.interval <= self.total_steps:
            raise ValueError(
                f"interval must be a whole number of environment steps in [1, total_steps="
                f"{self.total_steps}], got {self.interval!r}"
            )
        if self.targets not in TARGET_MODES:
            raise ValueError(
                f"federation.targets must be one of {', '.join(TARGET_MODES)}, got {self.targets!r}"
            )
        if self.weighting not in WEIGHTINGS:
            raise ValueError(
                f"federation.weighting must be one of {', '.join(WEIGHTINGS)}, "
                f"got {self.weighting!r}"
            )
        if self.initial_model is not None and self.initial_model not in INITIAL_MODELS:
            raise ValueError(
                f"federation.initial_model must be one of {', '.join(INITIAL_MODELS)} (or null), "
                f"got {self.initial_model!r}"
            )

    @property
    def shares_initial_model(self) -> bool:
        """Whether all clients start from one initial model (see ``initial_model``)."""
        default = "shared" if self.aggregates else "independent"
        return (self.initial_model or default) == "shared"

    @property
    def aggregates(self) -> bool:
        """Whether rounds end in FedAvg (only the ``fedavg`` scheme)."""
        return self.scheme == "fedavg"

    @property
    def client_tasks(self) -> tuple[str, ...]:
        """One entry per vehicle: ``("random",)`` for ``central``, else the fleet's tasks,
        ``tasks`` repeated ``vehicles_per_task`` times (vehicle i has task i mod len(tasks))."""
        if self.scheme == "central":
            return ("random",)
        return self.tasks * self.vehicles_per_task

    @property
    def fleet_size(self) -> int:
        """Vehicles (clients) in the run."""
        return len(self.client_tasks)

    @property
    def test_tasks(self) -> tuple[str, ...]:
        """The distinct tasks, in order: what every scheme is tested on."""
        return tuple(dict.fromkeys(self.tasks))

    @property
    def vehicles_drawn(self) -> int:
        """Vehicles that train in each round (the whole fleet unless sampling)."""
        if self.vehicles_per_round is not None:
            return self.vehicles_per_round
        return max(1, math.floor(self.fraction_train * self.fleet_size))

    @property
    def samples(self) -> bool:
        """Whether rounds draw a part of the fleet."""
        return self.vehicles_drawn < self.fleet_size

    @property
    def num_rounds(self) -> int:
        return math.ceil(self.total_steps / self.interval)

    def round_steps(self, round_index: int) -> int:
        """Environment steps per client in round ``round_index`` (0-based)."""
        start = round_index * self.interval
        return max(0, min(self.interval, self.total_steps - start))

    def round_end_step(self, round_index: int) -> int:
        return min((round_index + 1) * self.interval, self.total_steps)

    def model_files(self, client_names: list[str]) -> dict[str, str | list[str]]:
        """Which model file(s) (under ``models/``) are tested on each task.

        FedAvg-DDPG: the one global model on every task. Central-DDPG: its one model on
        every task. Sep-DDPG: each vehicle's own model on its task; a task with several
        vehicles lists them all, and its test figures pool their episodes.
        """
        if self.scheme == "fedavg":
            return {task: "global.pt" for task in self.test_tasks}
        if self.scheme == "central":
            return {task: "central.pt" for task in self.test_tasks}
        files: dict[str, list[str]] = {task: [] for task in self.test_tasks}
        for task, name in zip(self.client_tasks, client_names, strict=True):
            files[task].append(f"{name}.pt")
        return {task: names[0] if len(names) == 1 else names for task, names in files.items()}


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def client_seeds(seed: int, num_clients: int) -> list[tuple[int, int]]:
    """``(agent_seed, env_seed)`` of each client, from ``SeedSequence(seed).spawn(n)``."""
    seeds = []
    for child in np.random.SeedSequence(int(seed)).spawn(num_clients):
        agent_seed, env_seed = child.generate_state(2, np.uint32)
        seeds.append((int(agent_seed), int(env_seed)))
    return seeds


_SAMPLING_BRANCH = 0x5A3D
"""Spawn-key root of the per-round draws of the vehicles that train."""


def round_sample(seed: int, round_index: int, candidates: Sequence[int], count: int) -> list[int]:
    """The ``count`` vehicles (of ``candidates``, their indices) that train in round
    ``round_index`` of run ``seed``, in index order; all of them if ``count`` covers them.

    Drawn without replacement from ``SeedSequence(seed, spawn_key=(0x5A3D, round))``, so a
    resumed run draws the same vehicles.
    """
    candidates = sorted(candidates)
    if count >= len(candidates):
        return candidates
    branch = np.random.SeedSequence(int(seed), spawn_key=(_SAMPLING_BRANCH, int(round_index)))
    chosen = np.random.default_rng(branch).choice(len(candidates), size=count, replace=False)
    return sorted(candidates[int(i)] for i in chosen)


_INITIAL_MODEL_BRANCH = 0x1A17
"""Spawn-key root of the shared initial model's seed, apart from every other stream."""


def initial_model_seed(seed: int) -> int:
    """Network-initialisation seed of the shared initial global model of run ``seed``."""
    branch = np.random.SeedSequence(int(seed), spawn_key=(_INITIAL_MODEL_BRANCH,))
    return int(branch.generate_state(1, np.uint32)[0])


_EVALUATION_BRANCH = 0xE7A1
"""Spawn-key root of the evaluation streams, apart from the clients' ``spawn()`` keys."""


def evaluation_seeds(seed: int, task: str, episodes: int) -> list[int]:
    """SUMO seeds of the test episodes of ``task``: odd, so never a training seed (even).

    They depend on the run seed and the task only, so every scheme trained with the same
    ``seed`` is tested on exactly the same traffic (common random numbers).
    """
    branch = np.random.SeedSequence(int(seed), spawn_key=(_EVALUATION_BRANCH, TASKS.index(task)))
    raw = branch.generate_state(episodes, np.uint32) if episodes else np.zeros(0, np.uint32)
    return [2 * (int(x) % _SEED_HALF_RANGE) + 1 for x in raw]


_ROUND_TEST_BRANCH = 0x7E57
"""Spawn-key root of the per-round test streams, apart from the final test's."""


def round_test_seeds(seed: int, task: str, episodes: int, final_episodes: int) -> list[int]:
    """SUMO seeds of the per-round test episodes of ``task`` (``round_test_episodes``).

    Odd, so never a training seed, from a branch of their own, and never one of the final
    test's ``final_episodes`` seeds: the curve and the final table meet different traffic.
    """
    final = set(evaluation_seeds(seed, task, final_episodes))
    branch = np.random.SeedSequence(int(seed), spawn_key=(_ROUND_TEST_BRANCH, TASKS.index(task)))
    seeds: list[int] = []
    drawn = episodes
    while len(seeds) < episodes:
        # generate_state's words are a stream: drawing more keeps the first ones.
        raw = branch.generate_state(drawn, np.uint32)
        seeds = []
        for word in raw:
            candidate = 2 * (int(word) % _SEED_HALF_RANGE) + 1
            if candidate not in final and candidate not in seeds:
                seeds.append(candidate)
        drawn += episodes - len(seeds)
    return seeds[:episodes]
