"""Milliseconds per DDPG training step: frl at each precision beside Stable-Baselines3.

One training step = act + observe + update (one gradient step, batch 256) at the paper's
sizes: the 26 x 18 x 3 grid, hidden [512, 512, 256, 64], after ``learning_starts``. Every
agent replays the same scenes, recorded from the intersection (all three tasks, the ego
driving held random accelerations so that it waits, crosses, collides and arrives), so
the sparse first layer sees the sparsity it meets in training.

Stable-Baselines3's DDPG runs at Table II's settings on the same scenes, in the same
process and on the same threads: ``pip install -c constraints.txt -e '.[bench]'``
(Stable-Baselines3 is never a dependency of frl itself). Without it the script prints
frl's figures and says how to add the comparison.

    python benchmarks/agent_speed.py [--blocks 16] [--threads N] [--profile] [--device cpu]
        [--precisions float32,bf16] [--option n_step=1 ...] [--variant "NAME KEY=VALUE ..."]
        [--dense] [--skip-sb3] [--skip-floor] [--skip-peak] [--skip-buffer]
        [--scenes PATH.npz | --save-scenes PATH.npz]

``--option KEY=VALUE`` sets a DDPGConfig field of the frl agents (repeatable);
``--variant "NAME KEY=VALUE ..."`` adds a row of the default agent with those fields
(repeatable; ``guide=gap_acceptance`` installs the rule as its teacher, and
``env.route_observation=true`` gives it the route beside each grid). frl's
rows are Table II's agent (``agent=ddpg-paper``: one-step targets, an MLP on the flat
grid, a tanh actor) at each precision and frl's default agent (``agent=ddpg``: 5-step
targets, held warm-up actions, the vehicles encoder, inverting gradients) at its default
precision.

A last row is a lower bound, the eager-PyTorch floor: Table II's update reduced to what
any eager PyTorch implementation pays (its matmuls through autograd at the precision
``auto`` picks, the weight casts, fused Adam and the soft update, at full size), without
replay, acting or the first layer's gather (``--skip-floor`` leaves it out). How far
frl's Table II row sits above it is the per-operation work left to remove.

A second table says how close each row runs to this machine's limit (``--skip-peak``
leaves it out): its matrix products' FLOPs per step, counted on the real steps, and its
share of the peak, the time those same products take on their own, each timed alone on
fresh tensors of the same shapes, in this run and on these threads (matmul_peak.py), over
the step's time. The default agent's row is its training update, collision budget and
cost head included, made every step here (training makes one every ``train_freq`` = 8).
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import sys
import time
from collections.abc import Callable
from importlib.resources import files
from pathlib import Path

import numpy as np
import torch
import yaml
from gymnasium import spaces
from omegaconf import OmegaConf

from frl.agents import DDPG, DDPGConfig, ReplayBuffer
from frl.agents.functional import soft_update
from frl.agents.precision import has_native_bf16, resolve_precision
from frl.envs import TASKS, EnvConfig, IntersectionEnv
from frl.federation.workers import available_cores
from frl.policies import install_guide
from frl.train_config import ConfigError, check_device

# The helpers beside this script, also under PYTHONSAFEPATH=1 (docs/reproduction.md).
sys.path.insert(0, str(Path(__file__).resolve().parent))
from cpu_settings import configure_cpu_training
from matmul_peak import Arithmetic, measure_arithmetic

GRID_SHAPE = (26, 18, 3)
TABLE_II = {"n_step": 1, "warmup_hold_steps": 1.0, "encoder": "flat", "actor_update": "tanh"}
"""What frl's default agent adds to Table II, switched off (``agent=ddpg-paper``)."""


def default_agent_fields() -> dict:
    """The DDPGConfig fields of frl's training default, ``agent=ddpg`` (its preset file),
    which adds the vehicles encoder to the dataclass's defaults."""
    preset = OmegaConf.to_container(OmegaConf.load(files("frl.conf") / "agent" / "ddpg.yaml"))
    preset.pop("name")
    return DDPGConfig.from_dict(preset).to_dict()


def default_budget_fields() -> dict:
    """The agent fields the default budget (``budget=data``) adds, its collision budget,
    without its ``train_freq``: a row here times one update per step."""
    budget = OmegaConf.to_container(OmegaConf.load(files("frl.conf") / "budget" / "data.yaml"))
    fields = dict(budget["agent"])
    fields.pop("train_freq")
    return fields


BLOCK = 25


class RecordedScenes:
    """Observations, terminations and rewards recorded from the intersection (SUMO), or
    loaded from a file that :meth:`save` wrote (a machine without SUMO, a GPU host)."""

    def __init__(self, observations: np.ndarray, terminated: np.ndarray, rewards: np.ndarray):
        self.observations, self.terminated, self.rewards = observations, terminated, rewards

    @classmethod
    def record(cls, steps_per_task: int = 800, seed: int = 0) -> RecordedScenes:
        """Drive each task ``steps_per_task`` steps on held random accelerations."""
        rng = np.random.default_rng(seed)
        observations, ends = [], []
        for task in TASKS:
            env = IntersectionEnv(task=task)
            obs, _ = env.reset(seed=seed)
            action = np.zeros(1, np.float32)
            for _ in range(steps_per_task):
                if rng.random() < 1 / 20:  # held actions, as frl's warm-up drives
                    action = rng.uniform(-1, 1, size=1).astype(np.float32)
                next_obs, _, terminated, truncated, _ = env.step(action)
                observations.append(obs)
                ends.append(terminated)
                obs = next_obs
                if terminated or truncated:
                    obs, _ = env.reset()
            env.close()
        rewards = rng.normal(0.0, 0.1, size=len(ends)).astype(np.float32)
        return cls(np.stack(observations), np.array(ends), rewards)

    def save(self, path: Path) -> None:
        """Write the scenes to ``path`` (a compressed ``.npz``)."""
        np.savez_compressed(
            path, observations=self.observations, terminated=self.terminated,
            rewards=self.rewards,
        )  # fmt: skip

    @classmethod
    def load(cls, path: Path) -> RecordedScenes:
        """Scenes that :meth:`save` wrote; a file of another shape is refused."""
        with np.load(path, allow_pickle=False) as data:
            scenes = cls(data["observations"], data["terminated"], data["rewards"])
        if scenes.observations.shape[1:] != GRID_SHAPE or not (
            len(scenes.observations) == len(scenes.terminated) == len(scenes.rewards) > 0
        ):
            raise ValueError(f"{path}: not scenes of the {GRID_SHAPE} grid")
        return scenes

    @property
    def mean_nonzeros(self) -> float:
        return float(np.count_nonzero(self.observations) / len(self.observations))

    def replay(self) -> Callable[[], tuple[np.ndarray, float, bool]]:
        """A cursor of its own: each call gives the next scene, the reward for reaching it
        and whether it ends the episode, round and round."""
        position = -1

        def step() -> tuple[np.ndarray, float, bool]:
            nonlocal position
            position = (position + 1) % len(self.observations)
            i = position
            return self.observations[i], float(self.rewards[i]), bool(self.terminated[i])

        return step


class Learner:
    """One agent learning on the replayed scenes, a block of :data:`BLOCK` steps at a time,
    so that the agents of one run take turns and share the machine's ups and downs."""

    label: str

    def step(self) -> None:
        """One training step."""
        raise NotImplementedError

    device = torch.device("cpu")

    def steps(self, count: int) -> None:
        """``count`` training steps, untimed."""
        for _ in range(count):
            self.step()

    def arithmetic(self, steps: int = BLOCK) -> Arithmetic:
        """The matrix products of ``steps`` steps, counted and timed alone."""
        return measure_arithmetic(lambda: self.steps(steps), steps)

    def block(self) -> float:
        """Run one block; milliseconds per training step."""
        started = time.perf_counter()
        for _ in range(BLOCK):
            self.step()
        if self.device.type == "cuda":  # the block ends when its kernels do
            torch.cuda.synchronize(self.device)
        return (time.perf_counter() - started) / BLOCK * 1e3


class FrlLearner(Learner):
    """An frl DDPG: act + observe + update per step, after ``learning_starts`` + 50."""

    def __init__(
        self,
        label: str,
        config: DDPGConfig,
        scenes: RecordedScenes,
        route: bool = False,
        device: str = "cpu",
    ) -> None:
        self.label, self.device = label, torch.device(device)
        obs_space: spaces.Space = spaces.Box(-2.0, 2.0, GRID_SHAPE, dtype=np.float32)
        if route:  # the env's route_observation: the straight task, 10 m before the line
            route_space = spaces.Box(-10.0, 1.0, (4,), dtype=np.float32)
            obs_space = spaces.Dict({"grid": obs_space, "route": route_space})
        act_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
        self.agent = DDPG(obs_space, act_space, config, seed=0, device=device)
        install_guide(self.agent, EnvConfig())
        grids = scenes.replay()
        route_part = np.array([0.0, 1.0, 0.0, 1.0], np.float32)

        def with_route() -> tuple[object, float, bool]:
            grid, reward, terminated = grids()
            return {"grid": grid, "route": route_part}, reward, terminated

        self.next_scene = with_route if route else grids
        self.obs = self.next_scene()[0]
        for _ in range(config.learning_starts + 50):
            self.step()

    def step(self) -> None:
        agent = self.agent
        action = agent.act(self.obs, explore=True)
        next_obs, reward, terminated = self.next_scene()
        agent.observe(self.obs, action, reward, next_obs, terminated)
        # As training does, the losses stay on the device: reading them would wait for it.
        agent.update_unread()
        self.obs = next_obs
        if terminated:
            agent.episode_start()

    def profile(self) -> str:
        from torch.profiler import ProfilerActivity, profile

        with profile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(50):
                self.step()
        return prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=25)


class EagerFloor(Learner):
    """The part of a Table II update that any eager-PyTorch DDPG pays: a lower bound.

    Per step, on a float32 actor and critic of Table II's sizes (1,404 inputs, the
    hidden layers, one output): the hidden layers' matmuls in ``dtype`` through autograd
    (target actor and critic forward; critic forward and backward; actor forward, critic
    forward and backward to its input, actor backward); under bf16 also the casts of
    those layers' weights that autocast makes (target actor, target critic, the critic
    for its update and again for the actor's, the actor) and their gradients copied
    back to float32; fused Adam on the whole actor and critic; the soft update of both
    targets. The first layer's output is a ready-made batch (no gather, so the first
    layer gets no gradient, though Adam and the soft update cover it), the action enters
    the critic added to it, and there is no replay, acting or loss beyond a mean.
    """

    def __init__(self, config: DDPGConfig, dtype: torch.dtype) -> None:
        name = "bf16" if dtype == torch.bfloat16 else "float32"
        self.label = f"eager PyTorch floor, Table II update, {name}"
        self.dtype = dtype
        generator = torch.Generator().manual_seed(0)
        sizes = (int(np.prod(GRID_SHAPE)), *config.hidden_sizes, 1)

        def network() -> list[torch.Tensor]:
            weights = [
                torch.empty(fan_out, fan_in).uniform_(-1e-2, 1e-2, generator=generator)
                for fan_in, fan_out in itertools.pairwise(sizes)
            ]
            return weights + [torch.zeros(fan_out) for fan_out in sizes[1:]]

        self.actor, self.critic = network(), network()
        self.actor_target = [p.clone() for p in self.actor]
        self.critic_target = [p.clone() for p in self.critic]
        for param in self.actor + self.critic:
            # float32 trains the weights themselves; bf16 copies its gradients into these.
            param.requires_grad_(dtype == torch.float32)
            param.grad = torch.zeros_like(param)
        self.actor_optimizer = torch.optim.Adam(self.actor, lr=config.actor_lr, fused=True)
        self.critic_optimizer = torch.optim.Adam(self.critic, lr=config.critic_lr, fused=True)
        self.tau = config.tau
        shape = (config.batch_size, config.hidden_sizes[0])
        self.first = torch.randn(shape, generator=generator).to(dtype)
        self.next_first = torch.randn(shape, generator=generator).to(dtype)
        self.actions = torch.rand((config.batch_size, 1), generator=generator).to(dtype)

    @staticmethod
    def _hidden(params: list[torch.Tensor], first: torch.Tensor) -> torch.Tensor:
        """The layers after the first, from the first layer's output."""
        layers = len(params) // 2
        x = torch.relu(first)
        for index in range(1, layers):
            x = torch.addmm(params[layers + index], x, params[index].t())
            if index < layers - 1:
                x = torch.relu_(x)
        return x.float()

    def _cast(self, params: list[torch.Tensor], trainable: bool = False) -> list[torch.Tensor]:
        """The weights the matmuls read: bf16 copies (as autocast makes), or themselves.
        The first layer, which these matmuls never read, is left as it is."""
        if self.dtype == torch.float32:
            return params if trainable else [p.detach() for p in params]
        first = {0, len(params) // 2}
        return [
            p if index in first else p.to(self.dtype).requires_grad_(trainable)
            for index, p in enumerate(params)
        ]

    def _zero_float32_gradients(self, optimizer: torch.optim.Optimizer) -> None:
        """float32 accumulates into the weights' gradients; bf16 overwrites them."""
        if self.dtype == torch.float32:
            optimizer.zero_grad(set_to_none=False)

    @staticmethod
    def _gradients_to(params: list[torch.Tensor], copies: list[torch.Tensor]) -> None:
        if copies is params:  # float32: the gradients are already there
            return
        pairs = zip(params, copies, strict=True)
        used = [(p.grad, c.grad) for p, c in pairs if c is not p and c.grad is not None]
        torch._foreach_copy_([grad for grad, _ in used], [copy for _, copy in used])

    def step(self) -> None:
        with torch.no_grad():
            actor_target = self._cast(self.actor_target)
            critic_target = self._cast(self.critic_target)
            next_action = self._hidden(actor_target, self.next_first).to(self.dtype)
            next_q = self._hidden(critic_target, self.next_first + next_action)
        critic = self._cast(self.critic, trainable=True)
        self._zero_float32_gradients(self.critic_optimizer)
        q = self._hidden(critic, self.first + self.actions)
        (q - next_q).square().mean().backward()
        self._gradients_to(self.critic, critic)
        self.critic_optimizer.step()
        actor = self._cast(self.actor, trainable=True)
        self._zero_float32_gradients(self.actor_optimizer)
        critic_now = self._cast(self.critic)
        action = self._hidden(actor, self.first).to(self.dtype)
        (-self._hidden(critic_now, self.first + action).mean()).backward()
        self._gradients_to(self.actor, actor)
        self.actor_optimizer.step()
        soft_update(self.actor_target + self.critic_target, self.actor + self.critic, self.tau)


class StableBaselines3Learner(Learner):
    """Stable-Baselines3's DDPG at Table II's settings on the same scenes. A step is its
    collect (predict, env step, buffer add) and train (one gradient step), timed between
    consecutive steps inside ``learn``; each block is one ``learn`` call of BLOCK + 1 steps,
    so its set-up is outside the timed intervals."""

    def __init__(self, scenes: RecordedScenes) -> None:
        import gymnasium as gym
        import stable_baselines3
        from stable_baselines3 import DDPG as SB3DDPG
        from stable_baselines3.common.callbacks import BaseCallback
        from stable_baselines3.common.noise import OrnsteinUhlenbeckActionNoise

        self.label = f"Stable-Baselines3 {stable_baselines3.__version__} DDPG, Table II"
        next_scene = scenes.replay()

        class ReplayedEnv(gym.Env):
            observation_space = spaces.Box(-2.0, 2.0, GRID_SHAPE, dtype=np.float32)
            action_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

            def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple:
                super().reset(seed=seed)
                return next_scene()[0], {}

            def step(self, action: np.ndarray) -> tuple:
                obs, reward, terminated = next_scene()
                return obs, reward, terminated, False, {}

        class Clock(BaseCallback):
            def __init__(self) -> None:
                super().__init__()
                self.stamps: list[float] = []

            def _on_step(self) -> bool:
                self.stamps.append(time.perf_counter())
                return True

        self.clock = Clock()
        self.model = SB3DDPG(
            "MlpPolicy",
            ReplayedEnv(),
            learning_rate=1e-4,
            buffer_size=100_000,
            learning_starts=1_000,
            batch_size=256,
            tau=0.001,
            gamma=0.99,
            train_freq=1,
            gradient_steps=1,
            action_noise=OrnsteinUhlenbeckActionNoise(np.zeros(1), 0.3 * np.ones(1), theta=0.15),
            policy_kwargs={"net_arch": [512, 512, 256, 64]},
            seed=0,
            device="cpu",
        )
        self.model.learn(1_050)

    def steps(self, count: int) -> None:
        self.model.learn(count, reset_num_timesteps=False)

    def block(self) -> float:
        self.clock.stamps.clear()
        self.model.learn(BLOCK + 1, callback=self.clock, reset_num_timesteps=False)
        return float(np.mean(np.diff(self.clock.stamps))) * 1e3


def buffer_megabytes(scenes: RecordedScenes, transitions: int = 100_000) -> tuple[float, int]:
    """Array bytes of a full 100k-transition grid buffer of these scenes, and its row width."""
    buffer = ReplayBuffer(
        transitions,
        GRID_SHAPE,
        1,
        np.random.default_rng(0),
        sparse=True,
        sparse_width=DDPGConfig().sparse.capacity,
    )
    next_scene = scenes.replay()
    obs = next_scene()[0]
    for _ in range(transitions):
        next_obs, reward, terminated = next_scene()
        buffer.add(obs, np.zeros(1), reward, next_obs, terminated)
        obs = next_obs
    return buffer.nbytes / 1e6, buffer._obs.width


def print_shares_of_peak(learners: list[Learner], times: dict[str, list[float]]) -> None:
    """Each row's FLOPs per step and its share of this machine's peak on the same products."""
    print(
        "arithmetic per training step (matrix products; the peak: the same products timed "
        "alone, this run, these threads):"
    )
    print(f"  {'':<46} {'GFLOP':>7} {'GFLOP/s':>8} {'peak GFLOP/s':>13} {'share':>6}")
    for learner in learners:
        arithmetic = learner.arithmetic()
        step_seconds = float(np.median(times[learner.label])) / 1e3
        print(
            f"  {learner.label:<46} {arithmetic.flops_per_step / 1e9:7.3f} "
            f"{arithmetic.flops_per_step / step_seconds / 1e9:8.1f} "
            f"{arithmetic.peak_flops_per_second / 1e9:13.1f} "
            f"{arithmetic.share_of_peak(step_seconds):6.0%}"
        )


def parse_options(parser: argparse.ArgumentParser, items: list[str]) -> dict:
    defaults = DDPGConfig().to_dict()
    options = {}
    for item in items:
        key, _, value = item.partition("=")
        if key not in defaults or not value:
            parser.error(f"--option {item!r}: expected KEY=VALUE with a DDPGConfig field")
        kind = type(defaults[key])
        if defaults[key] is None:  # an option off by default (collision_budget): its YAML value
            options[key] = yaml.safe_load(value)
        else:
            options[key] = value.lower() in ("1", "true", "yes") if kind is bool else kind(value)
    return options


ROUTE_KEY = "env.route_observation"


def parse_variant(parser: argparse.ArgumentParser, text: str) -> tuple[str, dict, bool]:
    """``"NAME KEY=VALUE ..."``: the row's name, its DDPGConfig fields, and whether it
    observes the route (``env.route_observation=true``)."""
    name, *items = text.split()
    if not name or "=" in name:
        parser.error(f"--variant {text!r}: a variant starts with its name")
    route = f"{ROUTE_KEY}=true" in items
    items = [item for item in items if not item.startswith(f"{ROUTE_KEY}=")]
    return name, parse_options(parser, items), route


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blocks", type=int, default=16, help=f"timed blocks of {BLOCK} steps")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (all cores)")
    parser.add_argument("--precisions", default="float32,bf16")
    parser.add_argument("--profile", action="store_true", help="torch profile of frl's steps")
    parser.add_argument("--dense", action="store_true", help="also a dense first layer")
    parser.add_argument("--skip-sb3", action="store_true")
    parser.add_argument("--skip-floor", action="store_true", help="no eager-PyTorch floor")
    parser.add_argument("--skip-buffer", action="store_true")
    parser.add_argument("--skip-peak", action="store_true", help="no share of the peak")
    parser.add_argument(
        "--device", default="cpu", help="where frl's networks and updates run (cpu, cuda)"
    )
    parser.add_argument(
        "--scenes", type=Path, default=None, help="replay scenes saved with --save-scenes "
        "(a machine without SUMO) instead of recording them",
    )  # fmt: skip
    parser.add_argument("--save-scenes", type=Path, default=None, metavar="PATH.npz")
    parser.add_argument(
        "--option", action="append", default=[], metavar="KEY=VALUE", help="a DDPGConfig field"
    )
    parser.add_argument(
        "--variant", action="append", default=[], metavar='"NAME KEY=VALUE ..."',
        help="a row of the default agent with these fields",
    )  # fmt: skip
    args = parser.parse_args()
    if args.threads is not None and not 0 < args.threads <= available_cores():
        parser.error(
            f"--threads {args.threads}: this process may use 1 to {available_cores()} cores"
        )
    options = parse_options(parser, args.option)
    variants = [parse_variant(parser, text) for text in args.variant]
    precisions = args.precisions.split(",")
    try:
        device = check_device(args.device)
    except ConfigError as error:
        parser.error(str(error))
    for name in precisions:
        resolve_precision(name, device)  # an unknown name fails here, before any timing
    on_cpu = torch.device(device).type == "cpu"
    # The floor and Stable-Baselines3 are CPU rows: beside another device they would not pair.
    with_sb3 = (
        on_cpu and not args.skip_sb3 and importlib.util.find_spec("stable_baselines3") is not None
    )

    if args.scenes is not None and not args.scenes.is_file():
        parser.error(f"--scenes {args.scenes}: no such file")

    threads = configure_cpu_training(args.threads)
    try:
        scenes = RecordedScenes.load(args.scenes) if args.scenes else RecordedScenes.record()
    except ValueError as error:
        parser.error(str(error))
    if args.save_scenes is not None:
        scenes.save(args.save_scenes)
    native = has_native_bf16(device)
    print(
        f"torch {torch.__version__}, device {device}, {threads} threads, native bf16: "
        f"{'yes' if native else 'no (bf16 is emulated)'}; {len(scenes.observations)} "
        f"recorded scenes, {scenes.mean_nonzeros:.1f} non-zeros each; blocks of {BLOCK} "
        "steps, the agents taking turns"
    )
    if options:
        print(f"options: {options}")

    defaults = default_agent_fields()
    budget = default_budget_fields()

    def config(**fields: object) -> DDPGConfig:
        return DDPGConfig(**{**defaults, **fields})

    learners: list[Learner] = [
        FrlLearner(
            f"frl, Table II agent, {name}",
            config(**{**TABLE_II, **options, "precision": name}),
            scenes,
            device=device,
        )
        for name in precisions
    ]
    default = config(**{**budget, **options})
    used = resolve_precision(default.precision, device)
    resolved = f" ({used})" if used != default.precision else ""
    learners.append(
        FrlLearner(
            f"frl, default agent, {default.precision}{resolved}", default, scenes, device=device
        )
    )
    for name, fields, route in variants:
        try:
            variant = config(**{**budget, **options, **fields})
        except ValueError as error:
            parser.error(f"--variant {name}: {error}")
        learners.append(
            FrlLearner(f"frl, default agent + {name}", variant, scenes, route, device=device)
        )
    if args.dense:
        dense = config(**{**TABLE_II, **options, "sparse": {"input": False}})
        learners.append(
            FrlLearner("frl, Table II agent, dense first layer", dense, scenes, device=device)
        )
    if on_cpu and not args.skip_floor:
        bf16 = resolve_precision("auto", "cpu") == "bf16"
        floor_dtype = torch.bfloat16 if bf16 else torch.float32
        learners.append(EagerFloor(config(**{**TABLE_II, **options}), floor_dtype))
    if with_sb3:
        learners.append(StableBaselines3Learner(scenes))
    if args.profile:
        for learner in learners:
            if isinstance(learner, FrlLearner):
                print(learner.label)
                print(learner.profile())

    times: dict[str, list[float]] = {learner.label: [] for learner in learners}
    for _ in range(args.blocks):
        for learner in learners:
            times[learner.label].append(learner.block())
    for label, blocks in times.items():
        print(
            f"{label:<46} {np.median(blocks):6.1f} ms/step "
            f"(median of {len(blocks)} blocks; best {min(blocks):.1f})"
        )

    if with_sb3:
        reference = float(np.median(times[learners[-1].label]))
        print("speed-up over Stable-Baselines3 per training step (same scenes, same threads):")
        for learner in learners[:-1]:
            ratio = reference / float(np.median(times[learner.label]))
            print(f"  {learner.label:<44} {ratio:5.2f}x")
    elif not on_cpu:
        print(f"on {device}: frl's rows only (the floor and Stable-Baselines3 are CPU rows)")
    elif not args.skip_sb3:
        print(
            "Stable-Baselines3 is not installed, so there is no side-by-side figure: "
            "pip install -c constraints.txt -e '.[bench]'"
        )

    if not args.skip_peak:
        print_shares_of_peak(learners, times)

    if not args.skip_buffer:
        megabytes, width = buffer_megabytes(scenes)
        dense_mb = 100_000 * 2 * np.prod(GRID_SHAPE) * 4 / 1e6
        print(
            f"replay buffer: {megabytes:.1f} MB for 100,000 grid transitions "
            f"(exact, {width} non-zeros/row; dense float32 would be {dense_mb:.0f} MB)"
        )


if __name__ == "__main__":
    main()
