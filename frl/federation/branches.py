"""Counterfactual branches at the entry decision: the road not taken, driven and undone.

A car that learns from its own driving sees, at each state near the stop line, what one
decision led to: going or waiting, never both. Where it branches
(:class:`frl.agents.BranchConfig`), a vehicle saves its simulation, drives the opposite of
the action it chose for a few steps and its exploring policy after them, stores that
branch in the replay buffer, and restores the simulation, so the car's own episode goes
on exactly as if nothing had happened (:meth:`frl.envs.IntersectionEnv.restore`). The
critics then learn from the same state what the other decision was worth: a controlled
experiment where the car's own driving gives one sample (rollout sampling, Dimitrakakis
and Lagoudakis 2008; restarts from saved states, Go-Explore).
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from frl.agents import DDPG, BranchConfig
from frl.agents.transitions import ObservedStep
from frl.envs import IntersectionEnv

BRANCH_STREAM = 0x6272616E
"""Tag of the branches' random stream among the vehicle's (``SeedSequence([seed, tag])``)."""


@dataclass
class BranchOutcomes:
    """How the branches of one kind ended (their counts)."""

    branches: int = 0
    collisions: int = 0
    arrivals: int = 0
    own_collisions: int = 0
    """Of the same episodes, how many the car's own driving ended in a collision."""


@dataclass
class BranchTally:
    """The branches a vehicle drove: ``brake`` where it went, ``go`` where it braked."""

    brake: BranchOutcomes = field(default_factory=BranchOutcomes)
    go: BranchOutcomes = field(default_factory=BranchOutcomes)

    def to_dict(self) -> dict[str, dict[str, int]]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, dict[str, int]]) -> BranchTally:
        return cls(BranchOutcomes(**data["brake"]), BranchOutcomes(**data["go"]))


def branch_lines(tallies: dict[str, dict[str, dict[str, int]]]) -> list[str]:
    """One line per branching vehicle, for the log: each kind's count and outcomes."""
    lines = []
    for vehicle, tally in tallies.items():
        parts = []
        for kind in ("brake", "go"):
            counts = tally[kind]
            share = {key: _share(counts[key], counts["branches"]) for key in counts}
            parts.append(
                f"{kind} {counts['branches']} (collided {share['collisions']}, arrived "
                f"{share['arrivals']}; the car's own episode collided {share['own_collisions']})"
            )
        lines.append(f"{vehicle}: " + ", ".join(parts))
    return lines


def _share(count: int, total: int) -> str:
    return f"{100 * count / total:.1f}%" if total else "-"


class Brancher:
    """Decides where a vehicle branches, drives the branch, and restores the drive.

    Args:
        config: where and how to branch.
        seed: the vehicle's agent seed (the branch decisions' stream is a child of it).
    """

    def __init__(self, config: BranchConfig, seed: int) -> None:
        self.config = config
        self.rng = np.random.default_rng(np.random.SeedSequence([int(seed), BRANCH_STREAM]))
        self.branched = False
        """Whether the running episode has branched (once an episode at most)."""
        self.pending_kind: str | None = None
        """The running episode's branch kind, until its own outcome is known."""
        self.tally = BranchTally()

    def episode_start(self) -> None:
        self.branched, self.pending_kind = False, None

    def due(self, env: IntersectionEnv, agent: DDPG) -> bool:
        """Whether to branch on this step: within the zone, after the warm-up, not yet
        this episode, and the stream's draw (drawn only on such steps)."""
        if self.branched or agent.explorer.in_warmup(agent.num_env_steps):
            return False
        distance = env.stop_line_distance_m
        if not -self.config.past_line_m <= distance <= self.config.before_line_m:
            return False
        return bool(self.rng.random() < self.config.probability)

    def branch(
        self, env: IntersectionEnv, agent: DDPG, observation: Any, chosen: np.ndarray
    ) -> None:
        """Drive the opposite of ``chosen`` (the env action the explorer chose here) from
        ``observation``, then the exploring policy, to the branch's end; store it with
        the agent and put ``env`` back where it was."""
        saved = env.snapshot()
        went = float(agent.scale.to_unit(chosen)[0]) >= 0
        kind = "brake" if went else "go"
        opposite = agent.scale.from_unit(np.full(agent.action_dim, -1.0 if went else 1.0))
        # A copy of the explorer's noise drives the branch on, so the car's own episode
        # draws the noise it would have drawn without a branch.
        noise = copy.deepcopy(agent.explorer.noise)
        steps: list[ObservedStep] = []
        state = observation
        info: dict[str, Any] = {}
        while True:
            if len(steps) < self.config.hold_steps:
                action = opposite
            else:
                policy = agent.scale.to_unit(agent.predict(state, deterministic=True)[0])
                action = agent.scale.from_unit(np.clip(policy + noise(), -1.0, 1.0))
            next_state, reward, terminated, truncated, info = env.step(action)
            steps.append(
                ObservedStep(state, action, float(reward), next_state, terminated, info["cost"])
            )
            if terminated or truncated:
                break
            state = next_state
        agent.observe_branch(steps)
        env.restore(saved)
        outcomes = getattr(self.tally, kind)
        outcomes.branches += 1
        outcomes.collisions += bool(info["collision"])
        outcomes.arrivals += bool(info["arrived"])
        self.branched, self.pending_kind = True, kind

    def episode_end(self, collided: bool) -> None:
        """The car's own episode ended: count its outcome beside its branch's."""
        if self.pending_kind is not None:
            getattr(self.tally, self.pending_kind).own_collisions += bool(collided)
        self.pending_kind = None

    def state_dict(self) -> dict[str, Any]:
        """JSON-ready: the stream, the running episode's flags and the tally."""
        return {
            "rng": self.rng.bit_generator.state,
            "branched": self.branched,
            "pending_kind": self.pending_kind,
            "tally": self.tally.to_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.rng.bit_generator.state = state["rng"]
        self.branched = bool(state["branched"])
        self.pending_kind = state["pending_kind"]
        self.tally = BranchTally.from_dict(state["tally"])
