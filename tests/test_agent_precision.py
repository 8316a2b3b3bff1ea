"""agent.precision: bf16 autocast where the hardware has it, float32 state everywhere."""

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig, precision
from frl.agents.precision import float32_layer, resolve_precision

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def small(**overrides: object) -> DDPGConfig:
    return DDPGConfig(
        hidden_sizes=(64, 32), buffer_size=500, learning_starts=20, batch_size=16, **overrides
    )


def grid_obs(rng: np.random.Generator) -> np.ndarray:
    obs = np.zeros(GRID.shape, dtype=np.float32)
    for cell in rng.choice(26 * 18, size=int(rng.integers(2, 7)), replace=False):
        i, j = divmod(int(cell), 18)
        obs[i, j] = (rng.uniform(0, 1), rng.choice([-1.0, 0.0, 1.0]), 1.0)
    return obs


def train(agent: DDPG, steps: int) -> None:
    rng = np.random.default_rng(0)
    obs = grid_obs(rng)
    agent.episode_start()
    for t in range(steps):
        next_obs = grid_obs(rng)
        agent.observe(obs, agent.act(obs), float(rng.normal()), next_obs, t % 9 == 8)
        agent.update()
        obs = next_obs


def same_parameters(a: DDPG, b: DDPG) -> bool:
    state_a, state_b = a.federated_state(), b.federated_state()
    return state_a.keys() == state_b.keys() and all(
        torch.equal(state_a[key], state_b[key]) for key in state_a
    )


@pytest.fixture
def no_native_bf16(monkeypatch: pytest.MonkeyPatch) -> None:
    """A machine whose CPU has no bf16 instructions (and a fresh once-only warning)."""
    monkeypatch.setattr(precision, "cpu_has_native_bf16", lambda: False)
    monkeypatch.setattr(precision, "_warned_emulated", set())


@pytest.fixture
def native_bf16(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(precision, "cpu_has_native_bf16", lambda: True)


def test_unknown_precision_is_refused_naming_the_choices() -> None:
    with pytest.raises(ValueError, match=r"precision must be one of float32, bf16, auto"):
        DDPGConfig(precision="fp16")
    with pytest.raises(ValueError, match="precision must be one of"):
        resolve_precision("half", "cpu")


def test_auto_picks_bf16_only_where_it_is_native(native_bf16: None) -> None:
    assert resolve_precision("auto", "cpu") == "bf16"
    assert resolve_precision("float32", "cpu") == "float32"
    assert DDPG(GRID, ACCEL, small(precision="auto")).precision == "bf16"


@pytest.mark.usefixtures("no_native_bf16")
def test_auto_falls_back_to_float32_without_native_bf16_and_trains_exactly_as_float32() -> None:
    agent = DDPG(GRID, ACCEL, small(precision="auto"), seed=3)
    assert agent.precision == "float32"
    reference = DDPG(GRID, ACCEL, small(precision="float32"), seed=3)
    train(agent, 60)
    train(reference, 60)
    assert same_parameters(agent, reference)


@pytest.mark.usefixtures("no_native_bf16")
def test_explicit_bf16_on_emulating_hardware_warns_once_and_still_runs() -> None:
    with pytest.warns(RuntimeWarning, match="no native bf16.*slower than in float32"):
        first = DDPG(GRID, ACCEL, small(precision="bf16"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        second = DDPG(GRID, ACCEL, small(precision="bf16"))
    assert first.precision == second.precision == "bf16"
    train(second, 30)


def test_cpu_detection_reads_the_bf16_flags(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(precision.sys, "platform", "linux")
    monkeypatch.setattr(precision.platform, "machine", lambda: "x86_64")
    for flags, native in [
        ({"avx512f", "avx512_bf16"}, True),
        ({"amx_tile", "amx_bf16"}, True),
        ({"avx512f", "avx512bw", "avx2"}, False),  # AVX-512 alone: bf16 is emulated
        (set(), False),
    ]:
        monkeypatch.setattr(precision, "_cpu_flags", lambda flags=flags: frozenset(flags))
        assert precision.cpu_has_native_bf16() is native
    monkeypatch.setattr(precision.platform, "machine", lambda: "aarch64")
    monkeypatch.setattr(precision, "_cpu_flags", lambda: frozenset({"asimd", "bf16"}))
    assert precision.cpu_has_native_bf16()


@pytest.mark.usefixtures("native_bf16")
def test_bf16_trains_with_float32_weights_optimizer_state_and_outputs() -> None:
    agent = DDPG(GRID, ACCEL, small(precision="bf16"), seed=1)
    train(agent, 60)
    assert agent.num_updates > 0
    assert all(t.dtype == torch.float32 for t in agent.federated_state().values())
    for optimizer in (agent.actor_optimizer, agent.critic_optimizer):
        for state in optimizer.state.values():
            assert state["exp_avg"].dtype == state["exp_avg_sq"].dtype == torch.float32
    obs = grid_obs(np.random.default_rng(5))
    assert agent.act(obs, explore=False).dtype == np.float32
    assert agent.critic_values(obs[None], np.zeros((1, 1))).dtype == np.float64
    losses = agent.update()
    assert all(np.isfinite(value) for value in losses.values())


def test_bf16_changes_the_arithmetic_but_not_the_function() -> None:
    """Autocast is on (the numbers differ from float32's) and close (bf16 rounding only)."""
    exact = DDPG(GRID, ACCEL, small(precision="float32"), seed=2)
    mixed = DDPG(GRID, ACCEL, small(precision="bf16"), seed=2)
    rng = np.random.default_rng(7)
    observations = np.stack([grid_obs(rng) for _ in range(32)])
    actions = rng.uniform(-1, 1, size=(32, 1))
    q_exact = exact.critic_values(observations, actions)
    q_mixed = mixed.critic_values(observations, actions)
    assert not np.array_equal(q_exact, q_mixed)
    np.testing.assert_allclose(q_mixed, q_exact, rtol=0.05, atol=2e-4)


def test_output_layers_stay_float32_under_autocast() -> None:
    layer = torch.nn.Linear(64, 1)
    x = torch.randn(8, 64)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert layer(x).dtype == torch.bfloat16
        out = float32_layer(layer, x.bfloat16())
    assert out.dtype == torch.float32
    with torch.no_grad():
        expected = layer(x.bfloat16().float())
    assert torch.equal(out.detach(), expected)


@pytest.mark.usefixtures("native_bf16")
def test_a_bf16_checkpoint_resumes_exactly(tmp_path: Path) -> None:
    agent = DDPG(GRID, ACCEL, small(precision="bf16"), seed=4)
    train(agent, 40)
    agent.save(tmp_path / "agent.pt", include_buffer=True)
    restored = DDPG.from_checkpoint(tmp_path / "agent.pt", GRID, ACCEL)
    assert restored.precision == "bf16" and restored.config.precision == "bf16"
    train(agent, 20)
    train(restored, 20)
    assert same_parameters(agent, restored)


def test_checkpoints_written_before_the_option_read_as_float32(tmp_path: Path) -> None:
    agent = DDPG(GRID, ACCEL, small())
    path = tmp_path / "old.pt"
    agent.save(path)
    data = torch.load(path, weights_only=True)
    del data["config"]["precision"]
    torch.save(data, path)
    assert DDPG.from_checkpoint(path, GRID, ACCEL).config.precision == "float32"
