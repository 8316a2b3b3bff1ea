"""DDPG agent: acting, bootstrapping, determinism, federated state and checkpoints."""

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, CheckpointError, DDPGConfig, SparseRows, is_target_key
from frl.agents.precision import autocast

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
SMALL = DDPGConfig(hidden_sizes=(32, 16), buffer_size=500, learning_starts=20, batch_size=8)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def grid_obs(rng: np.random.Generator) -> np.ndarray:
    obs = np.zeros(GRID.shape, dtype=np.float32)
    for cell in rng.choice(26 * 18, size=int(rng.integers(1, 6)), replace=False):
        i, j = divmod(int(cell), 18)
        obs[i, j] = (rng.uniform(0, 1), rng.choice([-1.0, 0.0, 1.0]), 1.0)
    return obs


def run(agent: DDPG, steps: int, seed: int = 0) -> list[dict[str, float]]:
    """Feed ``steps`` synthetic grid transitions, updating after each."""
    rng = np.random.default_rng(seed)
    obs, losses = grid_obs(rng), []
    agent.episode_start()
    for t in range(steps):
        action = agent.act(obs)
        next_obs = grid_obs(rng)
        agent.observe(obs, action, float(rng.normal()), next_obs, terminated=t % 7 == 6)
        losses.append(agent.update())
        obs = next_obs
        if t % 7 == 6:
            agent.episode_start()
    return losses


def params(agent: DDPG) -> dict[str, torch.Tensor]:
    return agent.federated_state()


def test_importable_without_sumo_and_defaults_are_the_paper_network() -> None:
    agent = DDPG(GRID, ACCEL)
    assert agent.sparse and agent.buffer.sparse
    assert agent.federated_state()["actor.layers.0.weight"].shape == (512, 1404)
    assert agent.federated_state()["critic.layers.3.weight"].shape == (64, 256)
    assert agent.buffer.nbytes <= 100e6


def test_actions_are_float32_within_bounds_and_deterministic_without_explore() -> None:
    box = spaces.Box(np.array([-2.0, 0.0], np.float32), np.array([2.0, 0.5], np.float32))
    agent = DDPG(GRID, box, SMALL, seed=1)
    rng = np.random.default_rng(0)
    obs = grid_obs(rng)
    for _ in range(30):  # warm-up uniform actions
        a = agent.act(obs)
        assert a.dtype == np.float32 and a.shape == (2,) and box.contains(a)
        agent.observe(obs, a, 0.0, obs, False)
    for _ in range(30):  # policy + noise
        assert box.contains(agent.act(obs))
    np.testing.assert_array_equal(agent.act(obs, explore=False), agent.act(obs, explore=False))


def test_update_is_empty_before_learning_starts_then_counts() -> None:
    agent = DDPG(GRID, ACCEL, SMALL)
    losses = run(agent, 25)
    assert all(loss == {} for loss in losses[:19])
    assert set(losses[19]) == {"critic_loss", "actor_loss", "q_mean", "td_error"}
    assert agent.num_env_steps == 25 and agent.num_updates == 6


def test_an_update_leaves_no_gradients_behind() -> None:
    config = DDPGConfig(**{**SMALL.to_dict(), "collision_budget": 0.02})
    agent = DDPG(GRID, ACCEL, config)
    before = {k: v.clone() for k, v in params(agent).items()}
    run(agent, 25)
    assert agent.num_updates == 6 and any(
        not torch.equal(before[k], v) for k, v in params(agent).items()
    )
    networks = [agent.actor, agent.critic, agent.networks.cost_critic]
    assert all(p.grad is None for net in networks for p in net.parameters())


def test_train_freq_updates_every_nth_step() -> None:
    config = DDPGConfig(**{**SMALL.to_dict(), "train_freq": 2})
    agent = DDPG(GRID, ACCEL, config)
    run(agent, 26)
    assert agent.num_updates == 4  # env steps 20, 22, 24, 26


@pytest.mark.parametrize("terminated", [False, True])
def test_truncation_bootstraps_and_termination_does_not(terminated: bool) -> None:
    # One-step targets (Table II's agent); n-step transitions are tested in
    # test_agent_options.py.
    config = DDPGConfig(
        hidden_sizes=(16,), buffer_size=8, learning_starts=1, batch_size=4, n_step=1
    )
    agent = DDPG(GRID, ACCEL, config, seed=3)
    rng = np.random.default_rng(1)
    obs, next_obs = grid_obs(rng), grid_obs(rng)
    # A time-limit cut-off: gymnasium says truncated=True, terminated=False. Every sampled
    # transition is this one.
    for _ in range(4):
        agent.observe(obs, np.array([0.5]), 1.0, next_obs, terminated=terminated)

    def dense(x: np.ndarray) -> SparseRows:
        return SparseRows.from_dense(torch.from_numpy(x.reshape(1, -1)))

    with torch.no_grad():
        q = agent.critic(dense(obs), torch.tensor([[0.5]]))
        next_q = agent.critic_target(dense(next_obs), agent.actor_target(dense(next_obs)))
    target = 1.0 + (0.0 if terminated else 0.99 * next_q)
    loss = agent.update()["critic_loss"]
    assert loss == pytest.approx(float((q - target) ** 2), rel=1e-5)
    assert agent.buffer.terminated[0] == float(terminated)


def test_same_seed_same_parameters_different_seed_differs() -> None:
    a, b, c = (DDPG(GRID, ACCEL, SMALL, seed=s) for s in (7, 7, 8))
    for agent in (a, b, c):
        run(agent, 40)
    pa, pb, pc = params(a), params(b), params(c)
    assert all(torch.equal(pa[k], pb[k]) for k in pa)
    assert not torch.equal(pa["actor.layers.0.weight"], pc["actor.layers.0.weight"])


def test_init_seed_shares_the_networks_and_nothing_else() -> None:
    a, b = (DDPG(GRID, ACCEL, SMALL, seed=s, init_seed=99) for s in (7, 8))
    own = DDPG(GRID, ACCEL, SMALL, seed=7)
    pa, pb, po = params(a), params(b), params(own)
    assert all(torch.equal(pa[k], pb[k]) for k in pa)  # one initial model ...
    assert not torch.equal(pa["actor.layers.0.weight"], po["actor.layers.0.weight"])
    # ... while noise, replay sampling and warm-up actions still follow each agent's seed
    obs = grid_obs(np.random.default_rng(0))
    a.episode_start(), b.episode_start()
    assert a.act(obs, explore=True) != pytest.approx(b.act(obs, explore=True))


def test_no_global_rng_use() -> None:
    np_state, torch_state = np.random.get_state()[1].copy(), torch.get_rng_state()
    run(DDPG(GRID, ACCEL, SMALL), 30)
    np.testing.assert_array_equal(np.random.get_state()[1], np_state)
    assert torch.equal(torch.get_rng_state(), torch_state)


def test_sparse_and_dense_agents_share_initial_parameters_and_policy() -> None:
    sparse = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), "sparse": {"input": True}}))
    dense = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), "sparse": {"input": False}}))
    ps, pd = params(sparse), params(dense)
    assert ps.keys() == pd.keys() and all(torch.equal(ps[k], pd[k]) for k in ps)
    obs = grid_obs(np.random.default_rng(5))
    np.testing.assert_allclose(
        sparse.act(obs, explore=False), dense.act(obs, explore=False), rtol=1e-5, atol=1e-6
    )


def test_federated_state_round_trip_and_target_keys() -> None:
    source, sink = DDPG(GRID, ACCEL, SMALL, seed=1), DDPG(GRID, ACCEL, SMALL, seed=2)
    run(source, 30)
    state = source.federated_state()
    assert tuple(state) == source.federated_keys
    assert all(
        t.device.type == "cpu" and t.is_contiguous() and not t.requires_grad for t in state.values()
    )
    assert {k.split(".")[0] for k in state} == {"actor", "critic", "actor_target", "critic_target"}
    assert is_target_key("critic_target.layers.0.weight") and not is_target_key(
        "critic.layers.0.bias"
    )
    state["actor.layers.0.bias"].add_(1.0)  # a copy: the agent must not change
    assert not torch.equal(
        source.federated_state()["actor.layers.0.bias"], state["actor.layers.0.bias"]
    )
    sink.load_federated_state(state)
    received = sink.federated_state()
    assert all(torch.equal(received[k], state[k]) for k in state)
    obs = grid_obs(np.random.default_rng(0))
    state_again = source.federated_state()
    sink.load_federated_state(state_again)
    np.testing.assert_array_equal(sink.act(obs, explore=False), source.act(obs, explore=False))


def test_load_federated_state_is_strict() -> None:
    agent = DDPG(GRID, ACCEL, SMALL)
    before = agent.federated_state()
    missing = dict(before)
    del missing["critic_target.layers.1.bias"]
    with pytest.raises(ValueError, match=r"critic_target\.layers\.1\.bias"):
        agent.load_federated_state(missing)
    with pytest.raises(ValueError, match=r"extra\.key"):
        agent.load_federated_state({**before, "extra.key": torch.zeros(1)})
    wrong = {**before, "actor.layers.1.weight": torch.zeros(3, 3)}
    wrong["actor.layers.0.bias"] = torch.full_like(before["actor.layers.0.bias"], 5.0)
    with pytest.raises(ValueError, match=r"actor\.layers\.1\.weight"):
        agent.load_federated_state(wrong)
    after = agent.federated_state()  # nothing was half-loaded
    assert all(torch.equal(before[k], after[k]) for k in before)


def test_sync_targets_copies_online_networks() -> None:
    agent = DDPG(GRID, ACCEL, SMALL)
    run(agent, 30)
    state = agent.federated_state()
    assert not torch.equal(state["actor.layers.0.weight"], state["actor_target.layers.0.weight"])
    agent.sync_targets()
    state = agent.federated_state()
    for key in state:
        if is_target_key(key):
            assert torch.equal(state[key], state[key.replace("_target", "")])


def test_save_load_round_trip_gives_identical_actions_and_next_update(tmp_path: Path) -> None:
    agent = DDPG(GRID, ACCEL, SMALL, seed=4)
    run(agent, 40)
    path = tmp_path / "agent.pt"
    agent.save(path, include_buffer=True)
    restored = DDPG(GRID, ACCEL, SMALL, seed=99)  # different seed: all state must come from file
    restored.restore(path)
    assert (restored.num_env_steps, restored.num_updates) == (40, 21)
    obs = grid_obs(np.random.default_rng(9))
    for _ in range(3):  # exploration noise continues identically
        np.testing.assert_array_equal(restored.act(obs), agent.act(obs))
    losses_a, losses_b = run(agent, 5, seed=1), run(restored, 5, seed=1)
    assert losses_a == losses_b
    pa, pb = params(agent), params(restored)
    assert all(torch.equal(pa[k], pb[k]) for k in pa)
    # Loads with weights_only=True by construction; the classmethod rebuilds from the file.
    rebuilt = DDPG.from_checkpoint(path, GRID, ACCEL)
    assert rebuilt.config == SMALL and rebuilt.seed == 4


def test_save_without_buffer_resumes_with_empty_buffer(tmp_path: Path) -> None:
    agent = DDPG(GRID, ACCEL, SMALL)
    run(agent, 30)
    agent.save(tmp_path / "a.pt")
    restored = DDPG(GRID, ACCEL, SMALL)
    run(restored, 3)
    restored.restore(tmp_path / "a.pt")
    assert len(restored.buffer) == 0 and restored.num_env_steps == 30


def test_save_bytes_are_the_file_save_writes(tmp_path: Path) -> None:
    """A Flower vehicle sends them, and the roadside unit writes the same model file."""
    agent = DDPG(GRID, ACCEL, SMALL)
    run(agent, 30)
    agent.save(tmp_path / "a.pt")
    assert agent.save_bytes() == (tmp_path / "a.pt").read_bytes()


def test_truncated_corrupt_and_foreign_files_raise_checkpoint_error(tmp_path: Path) -> None:
    agent = DDPG(GRID, ACCEL, SMALL)
    good = tmp_path / "good.pt"
    agent.save(good)
    data = good.read_bytes()
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(data[: len(data) // 2])
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint" * 100)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3), "epoch": 1}, foreign)
    for path in (truncated, garbage, foreign):
        with pytest.raises(CheckpointError):
            agent.restore(path)
    assert issubclass(CheckpointError, ValueError)
    with pytest.raises(FileNotFoundError):
        agent.restore(tmp_path / "missing.pt")
    assert list(tmp_path.glob("*.tmp")) == []  # the atomic write left no temporary file


def test_checkpoint_of_another_config_or_version_raises(tmp_path: Path) -> None:
    path = tmp_path / "a.pt"
    DDPG(GRID, ACCEL, SMALL).save(path)
    other = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), "hidden_sizes": (16, 16)}))
    with pytest.raises(CheckpointError, match="hidden_sizes"):
        other.restore(path)
    data = torch.load(path, weights_only=True)
    data["version"] = 999
    torch.save(data, path)
    with pytest.raises(CheckpointError, match="version"):
        DDPG(GRID, ACCEL, SMALL).restore(path)


def test_rejects_unbounded_action_space() -> None:
    with pytest.raises(ValueError, match="finite"):
        DDPG(GRID, spaces.Box(-np.inf, np.inf, (1,)), SMALL)


def test_td_error_is_the_mean_absolute_gap_to_the_target() -> None:
    agent = DDPG(GRID, ACCEL, SMALL)
    run(agent, 25)
    # The critic loss is the mean squared TD error, so |TD| averages to at most its root.
    stats = run(agent, 1, seed=3)[0]
    assert 0 <= stats["td_error"] <= np.sqrt(stats["critic_loss"]) + 1e-6


def test_last_policy_action_is_nan_in_the_warm_up_then_the_noise_free_action() -> None:
    agent = DDPG(GRID, ACCEL, SMALL)
    obs = grid_obs(np.random.default_rng(0))
    agent.act(obs)
    assert np.isnan(agent.last_policy_action).all()  # uniform warm-up actions
    run(agent, 25)
    explored = agent.act(obs, explore=True)
    deterministic = agent.act(obs, explore=False)
    assert agent.last_policy_action == pytest.approx(deterministic.astype(np.float64))
    assert explored.shape == deterministic.shape


def test_critic_values_are_the_critics_q_of_env_unit_actions() -> None:
    agent = DDPG(GRID, ACCEL, SMALL)
    rng = np.random.default_rng(1)
    obs = np.stack([grid_obs(rng) for _ in range(4)])
    actions = np.array([[-1.0], [-0.5], [0.25], [1.0]], np.float32)
    values = agent.critic_values(obs, actions)
    with torch.no_grad(), autocast(agent.device, agent.precision):
        x = torch.from_numpy(obs.reshape(4, -1))
        inputs = SparseRows.from_dense(x) if agent.sparse else x
        expected = agent.critic(inputs, torch.from_numpy(actions)).numpy()
    assert values.shape == (4,)
    np.testing.assert_allclose(values, expected, rtol=1e-6)
