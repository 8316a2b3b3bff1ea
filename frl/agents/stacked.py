"""One update for many agents: the vehicles a process hosts learn in one call.

Every vehicle learns the same networks on a batch of the same shape, so K of them are
one batched update, not K small ones. :class:`StackedUpdate` holds each parameter of the
K agents as one tensor with a leading vehicle dimension, and each agent's parameter as a
view of its row: an agent acts, is averaged (FedAvg's in-place loads), checkpointed and
read exactly as before, and the stacked update moves all of them at once.

- The losses are the agent's own (:meth:`frl.agents.DDPG.critic_losses`, the
  constraint's :meth:`~frl.agents.constraint.CollisionConstraint.losses`,
  :meth:`~frl.agents.DDPG.actor_losses`), run under ``torch.func.vmap`` over the vehicles
  with ``functional_call`` on the first agent's networks: every matrix product becomes a
  batched one, and each vehicle's loss stays a mean over its own batch.
- The sum of the vehicles' losses has each vehicle's gradient in its own row, and Adam
  is element-wise, so one fused Adam step over the stacked tensors is each vehicle's own
  step (its moments are views of the stacked moments too; all agents share one step
  count, which is why they must stay in lockstep: every agent is due for an update at the
  same environment step, or none is).
- The agents act in one batched pass too (:meth:`StackedUpdate.policy_actions`): their
  actors vmapped over their stacked parameters, each on its own observation; each agent
  then adds its own exploration noise (:meth:`frl.agents.DDPG.act`'s ``policy_action``).
- Each agent samples its own batch with its own generator, as it would alone. The batched
  products are not the single ones bit for bit (another kernel), so a stacked run is its
  own run: one seed determines it, resumed or not, but it is not the run of the same
  vehicles updated one by one.

Anything that replaces an agent's tensors rather than writing into them (a checkpoint's
optimizer state) changes the *fingerprint*, the addresses of the tensors the agents hold,
checked before each update: the agents are then stacked afresh from what they hold.

On a GPU, where the agents would capture their own updates (``DDPGConfig.cuda_graph``),
the stacked update is captured as one CUDA graph per batch layout and replayed
(:mod:`frl.agents.update_graph`): the vehicles' batches are stacked on the host and
copied into the graph's static tensors, and the kernels and numbers are the eager
stacked update's.

On a CPU one vehicle's products already fill the cores, and the stacked update is no
faster (docs/benchmarks.md, "One update for a process's vehicles"); it is for a GPU.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterator, Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor, nn
from torch.func import functional_call, vmap

from frl.agents.acting import action_on_inputs, stacked_actor_inputs
from frl.agents.config import EXECUTION_FIELDS, DDPGConfig
from frl.agents.ddpg import DDPG
from frl.agents.functional import soft_update
from frl.agents.grid_vehicles import GridVehicles
from frl.agents.networks import TARGET_NAMES, make_adam
from frl.agents.replay_buffer import Batch
from frl.agents.sparse_linear import SparseRows
from frl.agents.update_graph import (
    GraphedUpdate,
    Packing,
    batch_tensors,
    keeps_one_layout,
    rebuild_batch,
)

Losses = dict[str, Tensor | float]


class StackedBatch(NamedTuple):
    """Every vehicle's batch: each of a batch's tensors stacked, one row per vehicle
    (None where a batch leaves a field empty), and one vehicle's batch, whose layout the
    stacked tensors have row by row."""

    tensors: list[Tensor | None]
    layout: Batch


def _rebuilt(template: StackedBatch, tensors: Iterator[Tensor | None]) -> StackedBatch:
    return StackedBatch([next(tensors) for _ in template.tensors], template.layout)


def _moved(batch: StackedBatch, device: torch.device) -> StackedBatch:
    return StackedBatch(
        [None if t is None else t.to(device, non_blocking=True) for t in batch.tensors],
        batch.layout,
    )


STACKED_PACKING = Packing(lambda batch: list(batch.tensors), _rebuilt, _moved)
"""How a graph copies a :class:`StackedBatch` in."""


def stacking_refusal(agents: Sequence[DDPG]) -> str | None:
    """Why ``agents`` cannot learn in one stacked update, in a sentence; None if they can."""
    if not agents:
        return "there are no agents to stack"
    first = agents[0]
    mine = _learning_config(first)
    for other in agents[1:]:
        theirs = _learning_config(other)
        differing = sorted(k for k in mine.keys() | theirs.keys() if mine.get(k) != theirs.get(k))
        if differing:
            return f"their agent configs differ in {differing[0]!r}"
        if (other.obs_shape, other.action_dim) != (first.obs_shape, first.action_dim):
            return "their observation or action spaces differ"
        if other.device != first.device or other.precision != first.precision:
            return "they learn on different devices or in different precisions"
        if other.layout.num_features != first.layout.num_features:
            return "their observations differ in features"
    refusal = config_refusal(first.config, first.obs_dim, first.device.type)
    if refusal is not None:
        return refusal
    if any(agent.proximal.mu > 0 for agent in agents):
        return "FedProx's pull (federation.strategy=fedprox) is not stacked"
    if any(agent.stacked_in is not None for agent in agents):
        return "an agent already learns in another stacked update"
    return None


def config_refusal(config: DDPGConfig, num_features: int, device_type: str) -> str | None:
    """Why agents of ``config`` on observations of ``num_features`` features cannot learn
    in one stacked update on a ``device_type`` device, known from the config alone; None
    if they can."""
    if not keeps_one_layout(config, config.use_sparse(num_features, device_type)):
        return (
            "their batches change shape from one update to the next (the flat encoder "
            "reading sparse rows; agent.encoder=vehicles, or agent.sparse.input=false, "
            "keeps one)"
        )
    return None


PER_AGENT_FIELDS: tuple[str, ...] = (
    *EXECUTION_FIELDS, "noise", "warmup_hold_steps", "guide_drives", "buffer_size",
    "collision_budget", "lagrange_gains", "lagrange_window",
)  # fmt: skip
"""Config fields stacked agents may differ in: each agent's own exploration, buffer and
multiplier, outside the update (a collision budget per task, say)."""


def _learning_config(agent: DDPG) -> dict[str, Any]:
    config = agent.config.to_dict()
    for name in PER_AGENT_FIELDS:
        config.pop(name, None)
    config["costed"], config["guided"] = agent.config.costed, agent.config.guided
    return config


class _Calls(nn.Module):
    """The first agent's networks as one module, so that ``functional_call`` can put any
    vehicle's parameters in them while one of the agent's own methods runs."""

    def __init__(self, networks: nn.Module) -> None:
        super().__init__()
        self.networks = networks

    def forward(self, method: Any, *args: Any) -> Any:
        return method(*args)


class StackedUpdate:
    """The updates of ``agents`` (same config, spaces, device), taken in one call.

    The agents' parameters and optimizer moments become views of stacked tensors here;
    :meth:`release` gives each its own again. While stacked, an agent refuses to update on
    its own (``DDPG.update`` raises): call :meth:`update_unread` for all of them.

    Raises:
        ValueError: the agents cannot be stacked (:func:`stacking_refusal` says why).
    """

    def __init__(self, agents: Sequence[DDPG]) -> None:
        refusal = stacking_refusal(agents)
        if refusal is not None:
            raise ValueError(f"these agents cannot learn in one stacked update: {refusal}")
        self.agents = list(agents)
        self.template = template = self.agents[0]
        self._calls = _Calls(template.networks)
        nets = template.networks
        self.names = [name for name, _ in nets.named_parameters()]
        self.pairs = [
            (f"{net}_target.{key}", f"{net}.{key}")
            for net in nets.names
            if net not in TARGET_NAMES
            for key, _ in getattr(nets, net).named_parameters()
        ]
        """(target, online) parameter names, in :meth:`ActorCritic.target_parameters`' order."""
        self.stacked: dict[str, Tensor] = {}
        """Each parameter of the networks, one row per agent (leaf tensors)."""
        self.optimizers: dict[str, torch.optim.Optimizer] = {}
        self.fingerprint: tuple[int, ...] = ()
        self._acting_pointers: tuple[int, ...] = ()
        """The agents' actor parameters' addresses when acting last found them stacked."""
        self.stackings = 0
        """Times the agents were stacked (their first action or update together, and after
        each replacement)."""
        device = template.device
        self.update_graph = (
            GraphedUpdate(self._step, device, self._tensors_read, packing=STACKED_PACKING)
            if template.config.cuda_graph and device.type == "cuda"
            else None
        )
        """The stacked update replayed as a CUDA graph; None where it runs eagerly (a CPU,
        ``cuda_graph=False``)."""
        for agent in self.agents:
            agent.stacked_in = self

    # ------------------------------------------------------------------ update
    def update_unread(self) -> list[Losses]:
        """One update of every agent where all are due: each agent's losses as tensors
        (as :meth:`frl.agents.DDPG.update_unread`), or an empty dict each. At the very
        start an n-step buffer may hold a batch in one agent and not yet in another: none
        updates until all can.

        Raises:
            RuntimeError: the agents have observed different numbers of steps.
        """
        at_step = {(agent.num_env_steps, _update_step(agent)) for agent in self.agents}
        if len(at_step) > 1:
            raise RuntimeError(
                "stacked agents out of lockstep: they have observed "
                f"{sorted(steps for steps, _ in at_step)} steps (they must observe as many)"
            )
        if not all(agent.update_due() for agent in self.agents):
            return [{} for _ in self.agents]
        self._stack_if_replaced()
        batch = self._batch()
        if self.update_graph is not None:  # it copies the host batch to its static one
            stats = self.update_graph(batch)
        else:
            stats = self._step(_moved(batch, self.template.device))
        losses: list[Losses] = []
        for k, agent in enumerate(self.agents):
            own: Losses = {name: value[k] for name, value in stats.items()}
            agent.num_updates += 1
            if agent.constraint is not None:
                own.update(agent.constraint.stats())
            losses.append(own)
        return losses

    # ------------------------------------------------------------------ acting
    def policy_actions(self, observations: Sequence[Any]) -> np.ndarray:
        """Every agent's deterministic policy action on its own observation (normalised,
        float64 ``[agents, action_dim]``), for :meth:`frl.agents.DDPG.act`'s
        ``policy_action``: the actors in one batched forward pass, in float32 as an agent
        acts alone (the batched products are not the single ones bit for bit).

        Raises:
            ValueError: not one observation per agent, or one of another shape.
        """
        if len(observations) != len(self.agents):
            raise ValueError(
                f"one observation per agent: {len(self.agents)} agents, "
                f"{len(observations)} observations"
            )
        template = self.template
        flats = [
            np.asarray(template.layout.flat(obs), np.float32).reshape(-1) for obs in observations
        ]
        if any(flat.size != template.obs_dim for flat in flats):
            raise ValueError(f"expected observations of shape {template.obs_shape}")
        # Acting reads the actors alone: the whole fingerprint (every parameter and moment
        # of every agent) is checked only where an actor's tensor was replaced.
        if not self.stacked or self._actor_pointers() != self._acting_pointers:
            self._stack_if_replaced()
            self._acting_pointers = self._actor_pointers()
        actor = template.networks.actor
        inputs = stacked_actor_inputs(actor, flats, template.device)
        params = {
            f"networks.{name}": tensor.detach()
            for name, tensor in self.stacked.items()
            if name.startswith("actor.")
        }

        def act(p: dict[str, Tensor], *parts: Tensor) -> Tensor:
            return functional_call(self._calls, p, (action_on_inputs, actor, *parts))

        with torch.no_grad():
            actions = vmap(act)(params, *inputs)
        return actions[:, 0].to("cpu", torch.float64).numpy()

    def _stack_if_replaced(self) -> None:
        """Stack the agents afresh where a tensor they hold was replaced (or never yet)."""
        if self._fingerprint() != self.fingerprint:
            self._stack()
            self.fingerprint = self._fingerprint()

    def _batch(self) -> StackedBatch:
        """Each agent's own sample, its vehicles padded to the most slots among them, the
        tensors stacked (one row per agent) on the host."""
        cfg = self.template.config
        batches = []
        for agent in self.agents:
            slots = agent.buffer.sample_slots(cfg.batch_size)
            batches.append(agent.buffer.gather(slots, agent.sparse, "cpu", cfg.encoder == "flat"))
        most = [max(_slots(field) for field in fields) for fields in zip(*batches, strict=True)]
        batches = [_padded(b, most) for b in batches]
        columns = [batch_tensors(b) for b in batches]
        assert all(c is not None for c in columns), "stacked agents keep one layout"
        tensors = [
            None if parts[0] is None else torch.stack(parts)
            for parts in zip(*columns, strict=True)  # type: ignore[misc]
        ]
        return StackedBatch(tensors, batches[0])

    def _step(self, batch: StackedBatch) -> dict[str, Tensor]:
        """The stacked update on a batch on the device: each loss with a row per agent."""
        return self._train_step(batch.tensors, batch.layout)

    def _tensors_read(self) -> list[Tensor]:
        """What the stacked update reads besides its batch and keeps from one update to
        the next: the stacked parameters and moments, the first agent's buffers, each
        agent's multiplier. A captured update replays on these very tensors."""
        tensors = [*self.stacked.values(), *self.template.networks.buffers()]
        for optimizer in self.optimizers.values():
            for state in optimizer.state.values():
                tensors += [value for value in state.values() if isinstance(value, Tensor)]
        for agent in self.agents:
            if agent.constraint is not None:
                constraint = agent.constraint
                tensors += [constraint.multiplier_now, constraint.price_denominator]
        return tensors

    def _train_step(self, tensors: list[Tensor | None], layout: Batch) -> dict[str, Tensor]:
        """:meth:`frl.agents.DDPG._train_step` for every agent at once."""
        template, calls = self.template, self._calls
        cfg = template.config
        params = {f"networks.{name}": tensor for name, tensor in self.stacked.items()}
        frozen = {name: tensor.detach() for name, tensor in params.items()}

        holes = [t is None for t in tensors]
        tensors = [t for t in tensors if t is not None]  # vmap maps tensors only

        def batch_of(parts: list[Tensor]) -> Batch:
            given = iter(parts)
            return rebuild_batch(layout, iter([None if h else next(given) for h in holes]))

        def critic_phase(p: dict[str, Tensor], parts: list[Tensor | None]) -> Any:
            return functional_call(calls, p, (template.critic_losses, batch_of(parts)))

        critic = vmap(critic_phase)(params, tensors)
        self._descend("critic", critic.loss)
        stats = dict(critic.stats)

        if template.constraint is not None:
            constraint = template.constraint

            def cost_losses(batch: Batch, *phase: Tensor) -> Any:
                return constraint.losses(batch, phase[0], template.discount(batch), *phase[1:])

            def cost_phase(p: dict[str, Tensor], parts: list[Tensor | None], *phase: Tensor) -> Any:
                return functional_call(calls, p, (cost_losses, batch_of(parts), *phase))

            cost_loss, cost_stats = vmap(cost_phase)(
                params, tensors, critic.next_actions, critic.hidden, critic.next_hidden
            )
            self._descend("cost_critic", cost_loss)
            stats.update(cost_stats)
        stats.update(self._actor_step(params, frozen, tensors, batch_of))
        soft_update(
            [self.stacked[target] for target, _ in self.pairs],
            [self.stacked[online] for _, online in self.pairs],
            cfg.tau,
        )
        return stats

    def _actor_step(
        self, params: dict[str, Tensor], frozen: dict[str, Tensor],
        tensors: list[Tensor | None], batch_of: Any,
    ) -> dict[str, Tensor]:  # fmt: skip
        """The actor's phase: as :meth:`frl.agents.DDPG._actor_step`, the critics read
        through detached parameters (no critic weight gradient)."""
        template, calls = self.template, self._calls
        actor_params = {
            name: params[name] if name.startswith("networks.actor.") else tensor
            for name, tensor in frozen.items()
        }
        price = self._prices()

        def preactivation_of(batch: Batch) -> Tensor:
            with template._autocast():
                return template.networks.actor.preactivation(batch.obs)

        if template.config.actor_update == "tanh":

            def tanh_losses(batch: Batch, *prices: Tensor) -> Any:
                preactivation = preactivation_of(batch)
                q_policy = template.objective(batch.obs, torch.tanh(preactivation), _pair(prices))
                return template.actor_losses(batch, preactivation, q_policy, None)

            def tanh_phase(
                p: dict[str, Tensor], parts: list[Tensor | None], *prices: Tensor
            ) -> Any:
                return functional_call(calls, p, (tanh_losses, batch_of(parts), *prices))

            loss, stats = vmap(tanh_phase)(actor_params, tensors, *price)
            self._descend("actor", loss)
            return stats

        def preactivation_phase(p: dict[str, Tensor], parts: list[Tensor | None]) -> Tensor:
            return functional_call(calls, p, (preactivation_of, batch_of(parts)))

        def objective_of(batch: Batch, action: Tensor, *prices: Tensor) -> Tensor:
            return template.objective(batch.obs, action, _pair(prices))

        def objective_phase(
            p: dict[str, Tensor], parts: list[Tensor | None], action: Tensor, *prices: Tensor
        ) -> Tensor:
            return functional_call(calls, p, (objective_of, batch_of(parts), action, *prices))

        def loss_phase(
            parts: list[Tensor | None], preactivation: Tensor, q_policy: Tensor, dq_da: Tensor
        ) -> Any:
            return template.actor_losses(batch_of(parts), preactivation, q_policy, dq_da)

        preactivation = vmap(preactivation_phase)(actor_params, tensors)
        action = template.bounded_action(preactivation)
        q_policy = vmap(objective_phase)(frozen, tensors, action, *price)
        (dq_da,) = torch.autograd.grad(q_policy.sum(), action)
        loss, stats = vmap(loss_phase)(tensors, preactivation, q_policy, dq_da)
        self._descend("actor", loss)
        return stats

    def _prices(self) -> tuple[Tensor, ...]:
        """Each agent's multiplier and 1 + multiplier, stacked; () without a budget."""
        if self.template.constraint is None:
            return ()
        constraints = [agent.constraint for agent in self.agents]
        return (
            torch.stack([c.multiplier_now for c in constraints]),  # type: ignore[union-attr]
            torch.stack([c.price_denominator for c in constraints]),  # type: ignore[union-attr]
        )

    def _descend(self, role: str, losses: Tensor) -> None:
        """One step of the role's stacked optimizer down the sum of the agents' losses:
        each agent's gradient lands in its own row."""
        optimizer = self.optimizers[role]
        optimizer.zero_grad(set_to_none=True)
        losses.sum().backward()
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)

    # ---------------------------------------------------------------- stacking
    def _optimizers_of(self, agent: DDPG) -> dict[str, torch.optim.Optimizer]:
        optimizers = {"actor": agent.actor_optimizer, "critic": agent.critic_optimizer}
        if agent.constraint is not None:
            optimizers["cost_critic"] = agent.constraint.optimizer
        return optimizers

    def _actor_pointers(self) -> tuple[int, ...]:
        """The addresses of every agent's actor parameters."""
        return tuple(
            p.data_ptr() for agent in self.agents for p in agent.networks.actor.parameters()
        )

    def _fingerprint(self) -> tuple[int, ...]:
        """The addresses of every tensor the agents hold for learning."""
        pointers: list[int] = []
        for agent in self.agents:
            pointers += [p.data_ptr() for p in agent.networks.parameters()]
            for optimizer in self._optimizers_of(agent).values():
                for state in optimizer.state.values():
                    pointers += [v.data_ptr() for v in state.values() if isinstance(v, Tensor)]
        return tuple(pointers)

    @torch.no_grad()
    def _stack(self) -> None:
        """Stack what the agents hold now into new tensors, and make each agent's
        parameters and optimizer moments views of its rows."""
        named = [dict(agent.networks.named_parameters()) for agent in self.agents]
        stacked = {}
        for name in self.names:
            rows = torch.stack([held[name].detach() for held in named])
            stacked[name] = rows.requires_grad_(named[0][name].requires_grad)
        views = [
            {name: nn.Parameter(stacked[name].detach()[k], named[k][name].requires_grad)
             for name in self.names}
            for k in range(len(self.agents))
        ]  # fmt: skip
        optimizers = {}
        for role, first in self._optimizers_of(self.template).items():
            order = _names_in(first, named[0])
            optimizer = make_adam([stacked[n] for n in order], _rate(first), self.template.device)
            owned = [self._optimizers_of(agent)[role] for agent in self.agents]
            held = [[opt.state.get(held_params[n], {}) for n in order]
                    for opt, held_params in zip(owned, named, strict=True)]  # fmt: skip
            new_states: list[dict[Tensor, dict[str, Tensor]]] = [{} for _ in self.agents]
            for j, name in enumerate(order):
                states = [per_agent[j] for per_agent in held]
                moments = _stacked_moments(name, states, stacked[name], first, self.template)
                optimizer.state[stacked[name]] = moments
                for k, own in enumerate(new_states):
                    own[views[k][name]] = {
                        "step": moments["step"],
                        "exp_avg": moments["exp_avg"][k],
                        "exp_avg_sq": moments["exp_avg_sq"][k],
                    }
            for k, opt in enumerate(owned):
                opt.param_groups[0]["params"] = [views[k][n] for n in order]
                opt.state = defaultdict(dict, new_states[k])
            optimizers[role] = optimizer
        for agent, own in zip(self.agents, views, strict=True):
            for name, view in own.items():
                module, leaf = _owner(agent.networks, name)
                module._parameters[leaf] = view
        self.stacked, self.optimizers = stacked, optimizers
        self.stackings += 1

    def release(self) -> None:
        """Give every agent tensors of its own again (copies of its rows) and let it
        learn alone."""
        with torch.no_grad():
            for agent in self.agents:
                named = dict(agent.networks.named_parameters())
                own = {
                    name: nn.Parameter(p.detach().clone(), p.requires_grad)
                    for name, p in named.items()
                }
                for optimizer in self._optimizers_of(agent).values():
                    order = _names_in(optimizer, named)
                    state = defaultdict(dict)
                    for name in order:
                        held = optimizer.state.get(named[name], {})
                        state[own[name]] = {k: v.clone() for k, v in held.items()}
                    optimizer.param_groups[0]["params"] = [own[n] for n in order]
                    optimizer.state = state
                for name, param in own.items():
                    module, leaf = _owner(agent.networks, name)
                    module._parameters[leaf] = param
                agent.stacked_in = None
        self.stacked, self.optimizers, self.fingerprint = {}, {}, ()
        if self.update_graph is not None:
            self.update_graph.drop()


def _update_step(agent: DDPG) -> bool:
    """Whether the agent's step count calls for an update (its buffer aside)."""
    cfg = agent.config
    return agent.num_env_steps >= cfg.learning_starts and agent.num_env_steps % cfg.train_freq == 0


def _pair(prices: tuple[Tensor, ...]) -> tuple[Tensor, Tensor] | None:
    return (prices[0], prices[1]) if prices else None


def _slots(value: Any) -> int:
    """Vehicle slots per grid of a batch's field (0: not rows with vehicles)."""
    if isinstance(value, SparseRows) and value.vehicles is not None:
        return int(value.vehicles.cell.shape[1])
    return 0


def _padded(batch: Batch, slots: list[int]) -> Batch:
    """``batch`` with each field's vehicles in ``slots[i]`` places per grid: padding
    slots, masked out, change neither the pooled sum nor the maximum."""
    fields: list[Any] = []
    for value, most in zip(batch, slots, strict=True):
        extra = most - _slots(value)
        if extra > 0:
            found = value.vehicles
            pad = torch.nn.functional.pad
            value = value._replace(
                vehicles=GridVehicles(
                    found.geometry,
                    pad(found.cell, (0, extra)),
                    pad(found.channels, (0, 0, 0, extra)),
                    pad(found.present, (0, extra)),
                    found.extra,
                )
            )
        fields.append(value)
    return Batch(*fields)


def _names_in(optimizer: torch.optim.Optimizer, named: dict[str, Tensor]) -> list[str]:
    """The names of an optimizer's parameters, in its order."""
    name_of = {id(param): name for name, param in named.items()}
    return [name_of[id(param)] for param in optimizer.param_groups[0]["params"]]


def _rate(optimizer: torch.optim.Optimizer) -> float:
    return float(optimizer.param_groups[0]["lr"])


def _stacked_moments(
    name: str, states: list[dict[str, Any]], stacked: Tensor,
    optimizer: torch.optim.Optimizer, template: DDPG,
) -> dict[str, Tensor]:  # fmt: skip
    """One parameter's Adam state for all agents: their moments stacked, their common
    step count; zeros before any step."""
    if not any(states):
        group = optimizer.param_groups[0]
        on_device = group.get("fused") or group.get("capturable")
        step = torch.zeros((), dtype=torch.float32, device=template.device if on_device else "cpu")
        zeros = torch.zeros_like(stacked, memory_format=torch.preserve_format)
        return {"step": step, "exp_avg": zeros, "exp_avg_sq": zeros.clone()}
    if not all(states):
        raise RuntimeError(f"stacked agents out of lockstep: some have taken no step on {name}")
    steps = {float(state["step"]) for state in states}
    if len(steps) != 1:
        raise RuntimeError(
            f"stacked agents out of lockstep: their optimizers have taken {sorted(steps)} "
            f"steps on {name}"
        )
    return {
        "step": states[0]["step"].clone(),
        "exp_avg": torch.stack([state["exp_avg"] for state in states]),
        "exp_avg_sq": torch.stack([state["exp_avg_sq"] for state in states]),
    }


def _owner(module: nn.Module, name: str) -> tuple[nn.Module, str]:
    """The submodule holding parameter ``name``, and the parameter's name there."""
    path, _, leaf = name.rpartition(".")
    return (module.get_submodule(path) if path else module), leaf
