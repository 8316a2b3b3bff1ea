"""Hyperparameters of the DDPG agent, defaulting to the paper's Table II."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from frl.agents.precision import PRECISIONS
from frl.agents.retired import without_retired, without_retired_critic

NOISE_KINDS: tuple[str, ...] = ("ou", "gaussian")
ENCODERS: tuple[str, ...] = ("flat", "vehicles")
ACTOR_UPDATES: tuple[str, ...] = ("tanh", "inverting_gradients")
GUIDES: tuple[str, ...] = ("none", "gap_acceptance", "committed_gap_acceptance")
CRITICS: tuple[str, ...] = ("expected", "quantile")
COST_CRITICS: tuple[str, ...] = ("separate", "head")
COST_TARGETS: tuple[str, ...] = ("n_step", "episode")

FIELDS_ADDED_LATER: dict[str, object] = {
    "warmup_hold_steps": 1.0,
    "n_step": 1,
    "precision": "float32",
    "encoder": "flat",
    "encoder_width": 64,
    "actor_update": "tanh",
    "guide": "none",
    "guide_weight": 0.0,
}
"""Fields that checkpoints and run configs written before them lack, with the values
those agents ran with (which are not today's defaults)."""


def agent_fields_as_run(data: dict[str, Any], saved: bool = True) -> dict[str, Any]:
    """Saved agent settings (a checkpoint's, a run config's) as the agent ran: the
    :data:`FIELDS_ADDED_LATER` they lack at their old values, retired options
    (:mod:`frl.agents.retired`) at their off values dropped; one at any other value
    raises :class:`frl.agents.retired.RetiredOptionError`. The one place both are read.
    ``saved=False``: a user's settings, whose ``cost_target`` is taken as given."""
    as_run = nested_fields({**FIELDS_ADDED_LATER, **data})
    if as_run.get("collision_budget") is not None:
        as_run.setdefault("cost_critic", "separate")  # budgets saved before the cost head
        as_run.setdefault("cost_target", "n_step")  # budgets saved before costs to go
    elif saved:
        as_run.pop("cost_target", None)  # "n_step" when saved before "episode" was the default
    if isinstance(as_run.get("critic"), dict):
        as_run["critic"] = without_retired_critic(as_run["critic"])
    return without_retired(as_run)


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


POSITIVE_INTS = (
    "buffer_size", "n_step", "batch_size", "train_freq",
    "sparse.min_features", "sparse.capacity", "encoder_width", "critic.quantiles",
    "lagrange_window",
)  # fmt: skip
_ANY: Callable[[float], bool] = math.isfinite
RANGES: dict[str, tuple[Callable[[float], bool], Callable[[float], bool], str]] = {
    "tau": (lambda v: v > 0, lambda v: v <= 1, "lie in (0, 1]"),
    "gamma": (lambda v: v >= 0, lambda v: v <= 1, "lie in [0, 1]"),
    "actor_lr": (lambda v: v > 0, _ANY, "be positive and finite"),
    "critic_lr": (lambda v: v > 0, _ANY, "be positive and finite"),
    "noise.sigma": (lambda v: v >= 0, _ANY, "be >= 0 and finite"),
    "noise.theta": (lambda v: v >= 0, _ANY, "be >= 0 and finite"),
    "noise.dt": (lambda v: v > 0, _ANY, "be positive and finite"),
    "warmup_hold_steps": (lambda v: v >= 1, _ANY, "be >= 1 and finite"),
    "guide_weight": (lambda v: v >= 0, _ANY, "be >= 0 and finite"),
    "guide_drives": (lambda v: v >= 0, lambda v: v <= 1, "lie in [0, 1]"),
    "critic.cvar_alpha": (lambda v: v > 0, lambda v: v <= 1, "lie in (0, 1]"),
}
"""Numeric fields (a group's as ``group.field``): (lower check, upper check, what the
message says). NaN fails both."""
CHOICES: dict[str, tuple[object, ...]] = {
    "noise.kind": NOISE_KINDS,
    "actor_update": ACTOR_UPDATES,
    "guide": GUIDES,
    "encoder": ENCODERS,
    "precision": PRECISIONS,
    "cuda_graph": (True, False),
    "sparse.input": (True, False, "auto"),
    "critic.kind": CRITICS,
    "cost_critic": COST_CRITICS,
    "cost_target": COST_TARGETS,
}
EXECUTION_FIELDS: tuple[str, ...] = ("cuda_graph",)
"""Fields that say how an update is launched, not what it computes: an agent loads a
checkpoint whatever they were when it was written."""
DEFAULT_LAGRANGE_GAINS: tuple[float, float, float] = (10.0, 0.1, 0.0)
"""The collision budget's PID gains (Kp, Ki, Kd); why these: :mod:`frl.agents.lagrange`."""


@dataclass(frozen=True)
class NoiseConfig:
    """The exploration noise, in normalised action units (``agent.noise.*``)."""

    kind: str = "ou"
    """``ou`` (Ornstein-Uhlenbeck, Table II) or ``gaussian``."""
    sigma: float = 0.3
    """Noise scale (keras-rl lineage of the paper: 0.3)."""
    theta: float = 0.15
    """OU mean-reversion rate (keras-rl lineage and SB3 default: 0.15)."""
    dt: float = 1e-2
    """OU time step (keras-rl and SB3 default: 1e-2)."""

    def __post_init__(self) -> None:
        _check_fields(self, "noise")
        # theta*dt >= 2 makes the discretised OU process oscillate with growing amplitude.
        _require(
            self.theta * self.dt < 2, "noise.theta * noise.dt must be < 2 for a stable OU process"
        )


@dataclass(frozen=True)
class SparseConfig:
    """Whether the first layers and the buffer read only an observation's non-zeros
    (``agent.sparse.*``)."""

    input: bool | str = "auto"
    """True, False, or ``"auto"`` (large observations only; on a GPU the flat encoder's
    first layer stays dense, so that the update can be captured)."""
    min_features: int = 256
    """``"auto"`` picks the sparse path (network and buffer) for obs with this many features."""
    capacity: int = 64
    """Initial non-zeros stored per observation in the compact buffer; grows, never truncates."""

    def __post_init__(self) -> None:
        _check_fields(self, "sparse")


@dataclass(frozen=True)
class CriticConfig:
    """What the reward critic learns, and what of it the actor climbs (``agent.critic.*``)."""

    kind: str = "expected"
    """``expected``, the mean return (DDPG), or ``quantile``, ``quantiles`` quantiles of the
    return (QR-DQN's quantile Huber loss), so that the actor can climb the CVaR of the
    return at ``cvar_alpha``."""
    quantiles: int = 32
    """Quantiles of the return a ``quantile`` critic learns."""
    cvar_alpha: float = 1.0
    """The actor climbs the mean of the worst ``cvar_alpha`` share of the return's quantiles
    (its CVaR); 1: the mean, as DDPG; below 1 needs ``critic.kind=quantile``."""

    def __post_init__(self) -> None:
        _check_fields(self, "critic")
        if self.kind != "quantile":
            _require(
                self.quantiles == CriticConfig.quantiles,
                "critic.quantiles is the quantile critic's: set critic.kind=quantile too",
            )
            _require(
                self.cvar_alpha == 1,
                "critic.cvar_alpha below 1 needs the return's quantiles: set critic.kind=quantile",
            )


GROUPS: dict[str, type] = {"noise": NoiseConfig, "sparse": SparseConfig, "critic": CriticConfig}
"""The nested option groups of :class:`DDPGConfig`, by field name."""

FLAT_KEYS: dict[str, tuple[str, str]] = {
    "noise_sigma": ("noise", "sigma"),
    "noise_theta": ("noise", "theta"),
    "noise_dt": ("noise", "dt"),
    "sparse_input": ("sparse", "input"),
    "sparse_min_features": ("sparse", "min_features"),
    "sparse_capacity": ("sparse", "capacity"),
    "quantiles": ("critic", "quantiles"),
    "cvar_alpha": ("critic", "cvar_alpha"),
}
"""The keys configs and checkpoints held before the groups, with their place now (a
plain ``noise`` or ``critic`` value was the group's ``kind``)."""


def nested_fields(data: dict[str, Any]) -> dict[str, Any]:
    """Saved agent settings with their flat keys (:data:`FLAT_KEYS`) moved into groups."""
    data = dict(data)
    groups: dict[str, dict[str, Any]] = {}
    for name in GROUPS:
        value = data.pop(name, None)
        if isinstance(value, dict):
            groups[name] = dict(value)
        else:
            groups[name] = {} if value is None else {"kind": value}
    for key, (group, name) in FLAT_KEYS.items():
        if key in data:
            groups[group][name] = data.pop(key)
    for name, values in groups.items():
        if values:
            data[name] = values
    return data


def flat_key_message(key: str) -> str | None:
    """The one line that names a flat key's new form, or None for any other key."""
    if key not in FLAT_KEYS:
        return None
    group, name = FLAT_KEYS[key]
    return f"agent.{key} is now agent.{group}.{name}"


def _check_fields(config: Any, prefix: str = "") -> None:
    """Check ``config``'s fields that :data:`POSITIVE_INTS`, :data:`RANGES` and
    :data:`CHOICES` name (a group's as ``prefix.field``)."""
    for f in fields(config):
        value = getattr(config, f.name)
        qualified = f"{prefix}.{f.name}" if prefix else f.name
        if qualified in POSITIVE_INTS:
            _require(
                _is_int(value) and value > 0,
                f"{qualified} must be a positive integer, got {value!r}",
            )
        if qualified in RANGES:
            low, high, text = RANGES[qualified]
            number = isinstance(value, (int, float)) and not isinstance(value, bool)
            _require(
                number and low(value) and high(value), f"{qualified} must {text}, got {value!r}"
            )
        if qualified in CHOICES:
            choices = CHOICES[qualified]
            _require(
                value in choices,
                f"{qualified} must be one of {', '.join(map(str, choices))}, got {value!r}",
            )


@dataclass(frozen=True)
class DDPGConfig:
    """DDPG hyperparameters: the paper's Table II where it gives a value, plus frl's
    choices that its learning studies credited (docs/studies.md): 5-step targets, held
    warm-up actions, an actor learning by inverting gradients, and bf16 matmuls where the
    hardware has them. For a grid observation frl's training adds the vehicles encoder
    (``agent=ddpg``); ``agent=ddpg-paper`` is Table II exactly.

    Noise parameters are in normalised action units: the actor's tanh output lives in
    [-1, 1] and is scaled to the action bounds only after noise is added. ``noise_sigma``
    is the OU process's sigma, not its spread: with theta 0.15 and dt 0.01 the process,
    restarted at 0 every episode, has a standard deviation of 0.07 after 5 steps, 0.13
    after 20 and 0.20 after 45, and its stationary 0.548 takes about 667 steps
    (:attr:`frl.agents.OrnsteinUhlenbeckNoise.stationary_variance`).
    """

    hidden_sizes: tuple[int, ...] = (512, 512, 256, 64)
    """Widths of the hidden layers of both actor and critic (Table II)."""
    buffer_size: int = 100_000
    """Replay buffer capacity in transitions (Table II)."""
    learning_starts: int = 1_000
    """Environment steps of uniform random actions before the first gradient step (Table II)."""
    batch_size: int = 256
    """Transitions per gradient step (Table II)."""
    tau: float = 0.001
    """Polyak coefficient of the soft target update, in (0, 1] (Table II)."""
    gamma: float = 0.99
    """Discount factor, in [0, 1] (Table II)."""
    actor_lr: float = 1e-4
    """Adam learning rate of the actor (Table II)."""
    critic_lr: float = 1e-4
    """Adam learning rate of the critic (Table II)."""
    train_freq: int = 1
    """Environment steps per update (1: one update per step, Table II's SB3)."""
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    """The exploration noise (Table II: OU, sigma 0.3)."""
    warmup_hold_steps: float = 20.0
    """Mean steps each uniform warm-up action is held (geometric durations); 1: a new
    action every step (Table II's SB3). Held actions drive long stretches of braking and
    of accelerating, so the first updates see waiting and going (docs/studies.md)."""
    n_step: int = 5
    """Steps summed in each critic target before bootstrapping (1: the one-step target of
    Table II). Five carry an arrival's +5 back to the decision to go five times faster
    (docs/studies.md)."""
    actor_update: str = "inverting_gradients"
    """How the actor bounds its action and learns: ``tanh`` (DDPG: a tanh output,
    gradients through it), or ``inverting_gradients`` (Hausknecht and Stone 2016): a
    clipped linear output whose gradient, dQ/da from the critic, is scaled by the room
    left towards the bound it points to, and reversed past it. Through a saturated tanh
    almost no gradient passes, so an actor stuck at full throttle cannot learn to brake
    where its critic has learned that it should."""
    guide: str = "none"
    """A teacher whose action is stored with every transition: ``none``;
    ``gap_acceptance``, frl's rule-based driver on the grid
    (:class:`frl.policies.GapAcceptancePolicy`); or ``committed_gap_acceptance``, the
    same rule told the distance to the stop line, which it reads from the student's
    route observation (``env.route_observation=true``). Installed by whoever drives the
    agent: :meth:`frl.agents.DDPG.set_guide`; frl's vehicles do. What the teacher's
    actions are used for: ``guide_weight``. An agent with a guide learns from the teacher
    as well as from its own driving: a guided agent, not the paper's."""
    guide_weight: float = 0.0
    """Weight of the imitation term in the actor's loss, the squared distance between the
    actor's action and the teacher's on every sampled state (DDPG from demonstrations,
    Nair et al. 2018, with the teacher asked on the learner's own states as DAgger does,
    and no Q-filter: docs/studies.md, "What each lever bought"); 0: no term."""
    guide_drives: float = 0.0
    """Share of training episodes the teacher drives, with the agent's exploration noise
    on its actions (DAgger's mixing, Ross et al. 2011, per episode; DART's noise, Laskey
    et al. 2017): each episode after the warm-up, the teacher takes the wheel with this
    probability, drawn from a generator of its own at the episode's first exploring
    step. Its transitions go into the replay buffer as the agent's own do; they do not
    count for the collision budget, which follows the agent's own driving. 0: the agent
    always drives."""
    sparse: SparseConfig = field(default_factory=SparseConfig)
    """Whether the networks and the buffer read the observation's non-zeros alone."""
    encoder: str = "flat"
    """What the MLPs read: ``flat``, the observation itself (Table II's MLP policy), or
    ``vehicles``, a grid observation as the set of vehicles it shows
    (:class:`frl.agents.vehicle_encoder.VehicleSetEncoder`, one per network)."""
    encoder_width: int = 64
    """Width of the ``vehicles`` encoder's per-vehicle MLP; it hands 2x this to the MLP."""
    precision: str = "auto"
    """What the forward and backward passes of updates and acting compute in: ``float32``,
    ``bf16`` (autocast; weights, optimizer state, targets, output layers and losses stay
    float32) or ``auto`` (bf16 where the device computes it natively, else float32);
    see :mod:`frl.agents.precision`."""
    cuda_graph: bool = True
    """On a CUDA device, capture the update as a CUDA graph once per batch layout and
    replay it (:mod:`frl.agents.update_graph`): the same kernels on the same numbers,
    launched at once. False: every update eager. Ignored on a CPU, and for batches whose
    shapes change (the flat encoder's sparse rows)."""
    collision_budget: float | None = None
    """Collisions per training episode the agent may average, in [0, 1): a cost critic
    learns the discounted collisions to come, and a Lagrange multiplier, driven by the
    recent training collision rate against this budget, prices them in the actor's
    objective (:mod:`frl.agents.lagrange`). None: no cost critic, the reward alone."""
    lagrange_gains: tuple[float, ...] = DEFAULT_LAGRANGE_GAINS
    """(Kp, Ki, Kd) of the multiplier's PID rule, per finished training episode, in reward
    units per collision and per unit of collision rate over budget."""
    lagrange_window: int = 50
    """Training episodes in the collision rate that the multiplier follows."""
    cost_critic: str = "head"
    """What learns the budget's Q_c: ``head``, a small MLP (one hidden layer as wide as
    the critic's last) on the reward critic's last hidden layer, which it reads without
    training it, so the reward critic learns as it does without a budget and the actor's
    objective takes one pass through the critic; or ``separate``, a critic of its own as
    large as the reward critic, with its own encoder, which doubles the critic's work in
    every update (how the two compare: docs/studies.md, "A cheaper cost critic: the
    head"). A budget saved before this field learned a separate critic, and loads as one."""
    cost_target: str = "episode"
    """What the cost critic learns towards: ``episode``, where the transition's episode
    terminated (a collision, an arrival), the discounted collisions to that end as they
    happened, with no bootstrap, and the n-step target only where a time limit cut the
    episode off (each episode's transitions then reach the buffer when it ends); or
    ``n_step``, the n-step TD target (the n-step discounted cost, then Q_c of its target
    network), as the reward critic does. ``episode`` collided less at five seeds of the
    default (docs/studies.md, "The cost critic on what each episode cost"); a budget saved
    before this field learned by n-step targets, and loads so."""
    critic: CriticConfig = field(default_factory=CriticConfig)
    """What the reward critic learns, and what of it the actor climbs."""

    def __post_init__(self) -> None:
        hidden = tuple(self.hidden_sizes)
        object.__setattr__(self, "hidden_sizes", hidden)
        _require(
            len(hidden) > 0 and all(_is_int(h) and h > 0 for h in hidden),
            f"hidden_sizes must name at least one hidden layer, as positive integers, got {hidden}",
        )
        _check_fields(self)
        _require(
            _is_int(self.learning_starts) and self.learning_starts >= 0,
            f"learning_starts must be a non-negative integer, got {self.learning_starts!r}",
        )
        _require(
            self.batch_size <= self.buffer_size,
            f"batch_size ({self.batch_size}) must not exceed buffer_size ({self.buffer_size})",
        )
        for name, group in GROUPS.items():
            if isinstance(getattr(self, name), dict):  # plain data (a preset, to_dict())
                object.__setattr__(self, name, group(**getattr(self, name)))
            _require(
                isinstance(getattr(self, name), group),
                f"{name} must be a {group.__name__}, got {getattr(self, name)!r}",
            )
        for name in ("guide_weight", "guide_drives"):
            _require(
                self.guide != "none" or getattr(self, name) == 0,
                f"{name} learns from a teacher: set guide to one of " + ", ".join(GUIDES[1:]),
            )
        self._check_cost_options()

    def _check_cost_options(self) -> None:
        budget = self.collision_budget
        if budget is not None:
            number = isinstance(budget, (int, float)) and not isinstance(budget, bool)
            _require(
                number and 0 <= budget < 1,
                f"collision_budget must lie in [0, 1) (collisions per episode), got {budget!r}",
            )
        gains = tuple(self.lagrange_gains)
        object.__setattr__(self, "lagrange_gains", gains)
        _require(
            len(gains) == 3
            and all(isinstance(g, (int, float)) and not isinstance(g, bool) for g in gains)
            and all(math.isfinite(g) and g >= 0 for g in gains),
            f"lagrange_gains must be three finite numbers >= 0 (Kp, Ki, Kd), got {gains!r}",
        )
        if budget is None:
            for name in ("lagrange_gains", "lagrange_window", "cost_critic", "cost_target"):
                _require(
                    getattr(self, name) == getattr(DDPGConfig, name),
                    f"{name} tunes the collision budget: set collision_budget too",
                )

    @property
    def costed(self) -> bool:
        """Whether the agent learns a cost critic under a collision budget."""
        return self.collision_budget is not None

    @property
    def costs_to_go(self) -> bool:
        """Whether the cost critic learns episodes' costs to go (``cost_target``)."""
        return self.costed and self.cost_target == "episode"

    @property
    def guided(self) -> bool:
        """Whether the agent stores a teacher's actions (``guide`` is not ``none``)."""
        return self.guide != "none"

    def use_sparse(self, num_features: int, device_type: str = "cpu") -> bool:
        """Whether observations of ``num_features`` features reach the networks as
        :class:`frl.agents.SparseRows` (the flat encoder's sparse first layer, or the
        vehicles encoder reading the non-zeros), on a ``device_type`` device."""
        if self.sparse.input != "auto":
            return bool(self.sparse.input)
        if device_type == "cuda" and self.encoder == "flat":
            # On a GPU a dense first layer is captured with the rest of the update
            # (cuda_graph); a sparse one, whose non-zeros change in number from batch to
            # batch, runs eagerly: Table II's step took 11.1 ms so and 2.9 ms dense.
            return False
        return num_features >= self.sparse.min_features

    def to_dict(self) -> dict[str, Any]:
        """Plain-type dict (lists for tuples), safe for ``torch.load(weights_only=True)``."""
        data = asdict(self)
        data["hidden_sizes"] = list(self.hidden_sizes)
        data["lagrange_gains"] = list(self.lagrange_gains)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any], saved: bool = True) -> DDPGConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ``TypeError``. Keys of
        :data:`FIELDS_ADDED_LATER` and retired keys as :func:`agent_fields_as_run` reads
        them; ``saved=False`` for a user's settings rather than a saved agent's."""
        data = agent_fields_as_run(data, saved)
        for name in ("hidden_sizes", "lagrange_gains"):
            if name in data:
                data[name] = tuple(data[name])
        return cls(**data)
