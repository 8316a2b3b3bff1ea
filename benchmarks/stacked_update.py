"""Does one stacked update of a process's vehicles beat one update per vehicle?

    python benchmarks/stacked_update.py [--vehicles 1,3,12] [--threads 1,2]
        [--precisions float32,bf16] [--repeats 30] [--device cpu]

Each vehicle learns the same networks on its own batch, so the vehicles a process hosts
could learn in one call: their parameters stacked (``torch.func.stack_module_state``),
the forward and backward passes under ``vmap(functional_call)``, which turns every
matrix product into a batched one, and one fused Adam step over the stacked tensors.
Adam is element-wise, so that step is each vehicle's own; the products are not bit for bit
the same (another kernel).

This script times the two ways on the default networks' dense shapes, a batch of 256
per vehicle: the vehicles encoder's MLP (4 -> 64 -> 64 on 8 slots per grid) and the
trunk (128 -> 512 -> 512 -> 256 -> 64 -> 1), forward, backward and Adam, at each
precision (bf16: autocast, as training) and thread count. It prints milliseconds per
vehicle and update, and the stacked way's speed over the loop's; it checks that the two
ways agree to rounding first.
"""

from __future__ import annotations

import argparse
import copy
import itertools
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch import nn
from torch.func import functional_call, stack_module_state, vmap

from frl.agents.networks import make_adam
from frl.agents.precision import autocast

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cpu_settings import configure_cpu_training

BATCH = 256
SLOTS = 8
"""Vehicle slots per grid: the default traffic's batches nearly always need 8."""


class TrunkAndEncoder(nn.Module):
    """The dense shapes of the default critic: an MLP over each grid's vehicle slots,
    pooled by sum and max, then the [512, 512, 256, 64] trunk."""

    def __init__(self) -> None:
        super().__init__()
        self.encoder = nn.Sequential(nn.Linear(4, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU())
        sizes = [128, 512, 512, 256, 64]
        layers: list[nn.Module] = []
        for fan_in, fan_out in itertools.pairwise(sizes):
            layers += [nn.Linear(fan_in, fan_out), nn.ReLU()]
        self.trunk = nn.Sequential(*layers, nn.Linear(64, 1))

    def forward(self, slots: torch.Tensor) -> torch.Tensor:
        encoded = self.encoder(slots)  # (batch, slots, 64)
        pooled = torch.cat([encoded.sum(-2), encoded.amax(-2)], dim=-1)
        return self.trunk(pooled)


def loss_of(output: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return (output.float() - target).square().mean()


def make_inputs(count: int, device: torch.device, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    slots = torch.randn(count, BATCH, SLOTS, 4, generator=generator).to(device)
    targets = torch.randn(count, BATCH, 1, generator=generator).to(device)
    return slots, targets


class LoopedUpdates:
    """One network and one fused Adam (the agent's) per vehicle, updated one after the other."""

    def __init__(self, networks: list[nn.Module], device: torch.device, precision: str) -> None:
        self.networks = networks
        self.optimizers = [make_adam(list(net.parameters()), 1e-4, device) for net in networks]
        self.device, self.precision = device, precision

    def step(self, slots: torch.Tensor, targets: torch.Tensor) -> list[torch.Tensor]:
        outputs = []
        for net, optimizer, x, y in zip(
            self.networks, self.optimizers, slots, targets, strict=True
        ):
            with autocast(self.device, self.precision):
                output = net(x)
            optimizer.zero_grad(set_to_none=True)
            loss_of(output, y).backward()
            optimizer.step()
            outputs.append(output.detach())
        return outputs


class StackedUpdate:
    """The vehicles' parameters stacked, one vmapped forward and backward, one fused Adam."""

    def __init__(self, networks: list[nn.Module], device: torch.device, precision: str) -> None:
        params, _ = stack_module_state(networks)
        self.params = {k: nn.Parameter(v.detach().clone()) for k, v in params.items()}
        self.template = copy.deepcopy(networks[0]).to("meta")
        self.optimizer = make_adam(list(self.params.values()), 1e-4, device)
        self.device, self.precision = device, precision

        def one_vehicle(p: dict[str, torch.Tensor], x: torch.Tensor) -> torch.Tensor:
            return functional_call(self.template, p, (x,))

        self.forward = vmap(one_vehicle)

    def step(self, slots: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        with autocast(self.device, self.precision):
            outputs = self.forward(self.params, slots)
        self.optimizer.zero_grad(set_to_none=True)
        # Each vehicle's loss is a mean over its own batch: their sum has each vehicle's
        # gradient in its own slice of the stacked parameters.
        sum(loss_of(outputs[i], targets[i]) for i in range(len(outputs))).backward()
        self.optimizer.step()
        return outputs.detach()


def timed(
    step: Callable[[torch.Tensor, torch.Tensor], object],
    slots: torch.Tensor,
    targets: torch.Tensor,
    repeats: int,
) -> float:
    for _ in range(5):
        step(slots, targets)
    if slots.device.type == "cuda":
        torch.cuda.synchronize()
    began = time.perf_counter()
    for _ in range(repeats):
        step(slots, targets)
    if slots.device.type == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - began) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", default="1,3,12")
    parser.add_argument("--threads", default="1,2")
    parser.add_argument("--precisions", default="float32,bf16")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: this machine has no CUDA device")
    counts = [int(v) for v in args.vehicles.split(",")]
    threads = [int(t) for t in args.threads.split(",")]
    precisions = args.precisions.split(",")
    print("| threads | precision | vehicles | loop ms per vehicle | stacked ms per vehicle "
          "| stacked speed-up |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for thread_count in threads:
        configure_cpu_training(thread_count)
        for precision in precisions:
            for count in counts:
                torch.manual_seed(0)
                networks = [TrunkAndEncoder().to(device) for _ in range(count)]
                looped = LoopedUpdates(copy.deepcopy(networks), device, precision)
                stacked = StackedUpdate(networks, device, precision)
                slots, targets = make_inputs(count, device, seed=count)
                first = torch.stack(looped.step(slots, targets)).float()
                agreement = (stacked.step(slots, targets).float() - first).abs().max().item()
                if agreement > (1e-2 if precision == "bf16" else 1e-4):
                    raise SystemExit(f"the stacked update disagrees by {agreement:.2e}")
                loop_s = timed(looped.step, slots, targets, args.repeats)
                stacked_s = timed(stacked.step, slots, targets, args.repeats)
                print(
                    f"| {thread_count} | {precision} | {count} | {1e3 * loop_s / count:.2f} "
                    f"| {1e3 * stacked_s / count:.2f} | {loop_s / stacked_s:.2f}x |"
                )


if __name__ == "__main__":
    main()
