"""The per-round test curve (``round_test_episodes``): the deployed model tested after
every round with exploration off, on a fixed small set of seeds per task.

The training curve (``rollout/ep_rew_mean``, Fig. 4's) mixes the policy with its
exploration noise; this curve does not. Each task's episodes run in a worker process of
their own (one SUMO each), apart from the vehicles, so a run trains exactly the same with
the curve on or off. The seeds (:func:`frl.federation.plan.round_test_seeds`) are
disjoint from the final test's.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from typing import Any

from torch import Tensor

from frl.agents import DDPG, DDPGConfig
from frl.envs import EnvConfig, IntersectionEnv, RewardConfig
from frl.episodes import EpisodeRecord, average_over_tasks, run_episodes, summarize
from frl.federation.workers import WorkerPool
from frl.policies import install_guide

ACTOR_PREFIX = "actor."
"""Keys of the online actor in a federated state: all a test drive needs."""


def actor_state(model: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """The online actor's entries of a federated state (what the test workers receive)."""
    return {key: value for key, value in model.items() if key.startswith(ACTOR_PREFIX)}


class TaskTester:
    """One task's test environment and the agents that drive it, in a worker process."""

    def __init__(
        self, env: EnvConfig, reward: RewardConfig, agent: DDPGConfig, device: str = "cpu"
    ) -> None:
        self.env = IntersectionEnv(env, reward)
        self.agent_config = agent
        self.device = device
        self.agents: list[DDPG] = []

    def _agent(self, index: int) -> DDPG:
        while len(self.agents) <= index:
            agent = DDPG(
                self.env.observation_space,
                self.env.action_space,
                self.agent_config,
                device=self.device,
            )
            install_guide(agent, self.env.config)  # a residual actor drives through it
            self.agents.append(agent)
        return self.agents[index]

    def run(
        self, task: str, seeds: list[int], actors: list[dict[str, Tensor]]
    ) -> list[EpisodeRecord]:
        """Each actor drives one episode per seed; their episodes pooled, in order."""
        records = []
        for index, actor in enumerate(actors):
            agent = self._agent(index)
            state = agent.federated_state()
            unexpected = sorted(set(actor) - {k for k in state if k.startswith(ACTOR_PREFIX)})
            if unexpected:
                raise ValueError(f"not an actor parameter: {unexpected[0]!r}")
            state.update(actor)
            agent.load_federated_state(state)
            act = functools.partial(agent.act, explore=False)
            records += run_episodes(self.env, act, task, seeds, agent.episode_start)
        return records

    def close(self) -> None:
        self.env.close()


class RoundTester:
    """Tests the deployed model(s) on every task's seeds, one worker process per task.

    Args:
        envs: each task's test environment (the training traffic).
        reward: the run's reward.
        agent: the run's agent config (networks, precision, guide).
        seeds: each task's SUMO seeds, the same every round.
        device: where the test agents run.
        num_threads: torch threads per worker.
        timeout_s: longest one round's tests may take in a worker (None: no limit).
    """

    def __init__(
        self,
        envs: Mapping[str, EnvConfig],
        reward: RewardConfig,
        agent: DDPGConfig,
        seeds: Mapping[str, Sequence[int]],
        device: str = "cpu",
        num_threads: int | None = None,
        timeout_s: float | None = None,
    ) -> None:
        if set(envs) != set(seeds):
            raise ValueError("envs and seeds must name the same tasks")
        self.tasks = list(envs)
        self.seeds = {task: [int(s) for s in seeds[task]] for task in self.tasks}
        factories = [
            (f"round_test_{task}", functools.partial(TaskTester, envs[task], reward, agent, device))
            for task in self.tasks
        ]
        self._pool = WorkerPool(factories, num_threads=num_threads, timeout_s=timeout_s)

    def __enter__(self) -> RoundTester:
        self._pool.start()
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self._pool.close(graceful=exc_type is None)

    def test(self, models: Mapping[str, Sequence[Mapping[str, Tensor]]]) -> dict[str, Any]:
        """Drive each task's model(s) on its seeds; ``{"per_task": {task: summary},
        "average": summary}`` (the keys of :func:`frl.episodes.summarize`).

        ``models`` maps every task to its deployed model(s), federated states or their
        actor entries: FedAvg-DDPG's one global model on every task, Sep-DDPG's vehicles of
        that task (their episodes pooled), Central-DDPG's one model on every task.
        """
        missing = [task for task in self.tasks if not models.get(task)]
        if missing:
            raise ValueError(f"no model to test on task {missing[0]!r}")
        records = self._pool.call(
            "run",
            args=[
                (task, self.seeds[task], [actor_state(m) for m in models[task]])
                for task in self.tasks
            ],
        )
        per_task = {
            task: summarize(task_records)
            for task, task_records in zip(self.tasks, records, strict=True)
        }
        return {"per_task": per_task, "average": average_over_tasks(per_task)}
