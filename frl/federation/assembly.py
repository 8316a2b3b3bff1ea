"""The federation's objects built from what a run is (:class:`TrainSettings`): each
vehicle's spec, the worker processes and their threads, the test environments and the
per-round tester."""

from __future__ import annotations

import dataclasses

from frl.agents import DDPGConfig
from frl.envs import EnvConfig
from frl.federation.client import ClientSpec
from frl.federation.plan import client_seeds, initial_model_seed, round_test_seeds
from frl.federation.round_tests import RoundTester
from frl.federation.run_settings import TrainSettings
from frl.federation.workers import available_cores, threads_per_worker


def client_specs(settings: TrainSettings) -> list[ClientSpec]:
    """One :class:`ClientSpec` per client of the scheme, seeded from the run seed."""
    plan = settings.plan
    tasks = plan.client_tasks
    init_seed = initial_model_seed(settings.seed) if plan.shares_initial_model else None
    envs = settings.vehicle_envs or (settings.env,) * len(tasks)
    mu = settings.strategy.proximal_mu if plan.aggregates else 0.0
    return [
        ClientSpec(
            index=index,
            task=task,
            env=envs[index],
            reward=settings.reward,
            agent=vehicle_agent(settings, task),
            agent_seed=agent_seed,
            env_seed=env_seed,
            device=settings.device,
            init_seed=init_seed,
            proximal_mu=mu,
        )
        for index, (task, (agent_seed, env_seed)) in enumerate(
            zip(tasks, client_seeds(settings.seed, len(tasks)), strict=True)
        )
    ]


def vehicle_agent(settings: TrainSettings, task: str) -> DDPGConfig:
    """The agent of a vehicle with ``task``: the run's, with its task's collision budget
    where ``agent.collision_budget_by_task`` sets one."""
    if settings.collision_budget_by_task is None:
        return settings.agent
    budget = settings.collision_budget_by_task[task]
    return dataclasses.replace(settings.agent, collision_budget=budget)


def worker_processes(settings: TrainSettings) -> int:
    """Worker processes of the processes backend: ``federation.workers`` if set, else one
    per vehicle while the fleet has at most max(cores, 3) vehicles (the paper's three keep
    a process each), else max(cores, 3), whose vehicles take turns."""
    fleet = settings.plan.fleet_size
    if settings.workers:
        return min(settings.workers, fleet)
    cores = settings.cores or available_cores()
    return min(fleet, max(cores, 3))


def worker_threads(settings: TrainSettings, num_workers: int) -> int:
    """Torch threads of each of ``num_workers`` processes: ``threads_per_worker`` if set,
    else the run's cores split evenly (at least one each)."""
    return settings.threads_per_worker or threads_per_worker(num_workers, settings.cores)


def evaluation_env(settings: TrainSettings, task: str) -> EnvConfig:
    """The test environment of ``task``: the training traffic (Section IV.B)."""
    return dataclasses.replace(settings.env, task=task)


def round_tester(settings: TrainSettings) -> RoundTester | None:
    """The per-round tester of the run (not started), or None where it has none."""
    if settings.round_test_episodes <= 0:
        return None
    tasks = settings.plan.test_tasks
    seeds = {
        task: round_test_seeds(
            settings.seed, task, settings.round_test_episodes, settings.eval_episodes
        )
        for task in tasks
    }
    return RoundTester(
        {task: evaluation_env(settings, task) for task in tasks},
        settings.reward,
        settings.agent,
        seeds,
        device=settings.device,
        num_threads=worker_threads(settings, len(tasks)),
        timeout_s=settings.worker_timeout_s,
    )
