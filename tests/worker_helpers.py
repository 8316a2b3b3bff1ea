"""Objects hosted by worker processes in the worker tests (importable by spawned children)."""

from __future__ import annotations

import os
import time

from frl.envs import SumoError


class Echo:
    """Answers calls; can sleep, raise, or exit hard."""

    def pid(self) -> int:
        return os.getpid()

    def add(self, a: int, b: int) -> int:
        return a + b

    def sleep(self, seconds: float) -> float:
        time.sleep(seconds)
        return seconds

    def fail(self) -> None:
        raise SumoError("SUMO lost its connection (simulated)")

    def exit_hard(self) -> None:
        os._exit(7)

    def chatty(self, steps: int, progress=None) -> int:
        for i in range(steps):
            progress(step=i + 1)
        return steps


class DenormalProbe:
    """Multiplies a denormal float by one, in this thread and in torch's other threads."""

    def products(self) -> tuple[float, float]:
        import torch

        denormal = torch.finfo(torch.float32).tiny / 4
        alone = (torch.tensor([denormal]) * 1.0).item()
        # Large enough that torch splits it over its threads: every chunk must flush too.
        many = torch.full((1 << 20,), denormal) * 1.0
        return alone, float(many.abs().max())


class BrokenAtStart:
    def __init__(self) -> None:
        raise SumoError("could not start SUMO (simulated)")
