"""The one learning test: DDPG swings up gymnasium's Pendulum-v1, trained by ``DDPG.learn``.

Pendulum episodes end only by the 200-step time limit (truncated, never terminated), so
learning here also depends on truncated transitions bootstrapping. Seeds 0-5 all reached
-120 to -270 mean return over the last 10 episodes at this budget; random play scores
about -1200 and the threshold is -400. The agent and the check are those of
``benchmarks/pendulum.py``, which also runs them in bf16 (most CPUs emulate it, slowly).
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.usefixtures("one_torch_thread")

_SPEC = importlib.util.spec_from_file_location(
    "pendulum", Path(__file__).resolve().parents[1] / "benchmarks" / "pendulum.py"
)
pendulum = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(pendulum)


@pytest.mark.slow
def test_learns_pendulum_swing_up() -> None:
    returns = pendulum.training_returns("float32", seed=0)
    assert len(returns) == pendulum.STEPS // 200
    assert np.mean(returns[-10:]) > pendulum.THRESHOLD, returns[-10:]
