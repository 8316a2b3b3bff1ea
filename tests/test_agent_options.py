"""The agent's opt-in learning options: n-step targets, held warm-up actions, the
pre-tanh penalty, held actions (action_repeat) and a rule-driven warm-up, each against
hand-computed numbers or its defining property."""

from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

from frl.agents import DDPG, CheckpointError, DDPGConfig
from frl.agents.n_step import NStepAccumulator

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
ACCEL = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
SMALL = DDPGConfig(hidden_sizes=(16,), buffer_size=200, learning_starts=10, batch_size=4)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _obs(value: float) -> np.ndarray:
    return np.full(3, value, np.float32)


def test_n_step_targets_by_hand():
    acc = NStepAccumulator(3, gamma=0.5)
    out = [acc.push(_obs(t), _obs(0), r, _obs(t + 1), False) for t, r in enumerate([1, 2, 4])]
    assert out[0] == [] and out[1] == []
    (first,) = out[2]
    # r0 + 0.5 r1 + 0.25 r2 = 1 + 1 + 1, from s0 to s3 over 3 steps
    assert first.reward == pytest.approx(3.0) and first.horizon == 3
    assert first.obs[0] == 0 and first.next_obs[0] == 3 and not first.terminated
    # The episode terminates: every pending step becomes a terminal transition.
    last = acc.push(_obs(3), _obs(0), 8, _obs(4), True)
    assert [t.horizon for t in last] == [3, 2, 1]
    assert [t.reward for t in last] == pytest.approx([2 + 2 + 2, 4 + 4, 8])
    assert all(t.terminated and t.next_obs[0] == 4 for t in last)
    assert len(acc) == 0


def test_n_step_flush_bootstraps_a_cut_off_episode():
    acc = NStepAccumulator(5, gamma=0.9)
    for t in range(2):
        assert acc.push(_obs(t), _obs(0), 1.0, _obs(t + 1), False) == []
    flushed = acc.flush()
    assert [(t.horizon, t.terminated) for t in flushed] == [(2, False), (1, False)]
    assert flushed[0].reward == pytest.approx(1.9) and flushed[0].next_obs[0] == 2


def test_an_n_step_agent_stores_k_step_transitions_and_discounts_by_gamma_k():
    config = DDPGConfig(**{**SMALL.to_dict(), "n_step": 3, "hidden_sizes": (16,)})
    agent = DDPG(GRID, ACCEL, config)
    rng = np.random.default_rng(0)
    obs = [rng.uniform(0, 1, GRID.shape).astype(np.float32) for _ in range(5)]
    agent.episode_start()
    for t in range(4):
        agent.observe(obs[t], np.array([0.5], np.float32), 1.0, obs[t + 1], terminated=False)
    assert len(agent.buffer) == 2  # steps 0 and 1 have their 3 successors
    agent.episode_start()  # a time limit cut the episode: the last two bootstrap
    assert len(agent.buffer) == 4
    assert agent.buffer.horizons[:4].tolist() == [3, 3, 2, 1]
    assert agent.buffer.rewards[0] == pytest.approx(1 + 0.99 + 0.99**2)
    assert agent.buffer.terminated[:4].tolist() == [0, 0, 0, 0]


def test_held_warm_up_actions_last_geometric_stretches():
    options = {"learning_starts": 2000, "warmup_hold_steps": 10.0, "hidden_sizes": (16,)}
    held = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), **options}))
    obs = np.zeros(GRID.shape, np.float32)
    actions = np.array([held.act(obs)[0] for _ in range(2000)])
    changes = int(np.sum(actions[1:] != actions[:-1]))
    assert 150 < changes < 250  # about one change in 10 steps
    assert actions.min() < -0.9 and actions.max() > 0.9  # still uniform over the range
    options = {"learning_starts": 100, "hidden_sizes": (16,), "warmup_hold_steps": 1.0}
    fresh = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), **options}))
    table_two = np.array([fresh.act(obs)[0] for _ in range(100)])
    assert np.all(table_two[1:] != table_two[:-1])  # hold 1 (Table II): a new one each step


def test_the_preactivation_penalty_pulls_a_saturated_actor_back():
    options = {"preactivation_l2": 1.0, "hidden_sizes": (16,), "actor_update": "tanh"}
    config = DDPGConfig(**{**SMALL.to_dict(), **options})
    agent = DDPG(GRID, ACCEL, config)
    with torch.no_grad():  # saturate the actor: a large output bias
        agent.actor.layers[-1].bias.fill_(5.0)
    rng = np.random.default_rng(1)
    agent.episode_start()
    for t in range(40):
        o = rng.uniform(0, 1, GRID.shape).astype(np.float32)
        agent.observe(o, np.array([1.0], np.float32), 0.0, o, terminated=t % 10 == 9)
    before = agent.actor.layers[-1].bias.item()
    for _ in range(20):
        agent.update()
    # Zero rewards give the critic nothing to pull with; the penalty alone lowers it.
    assert agent.actor.layers[-1].bias.item() < before


def test_options_survive_a_checkpoint_and_old_checkpoints_still_load(tmp_path: Path):
    config = DDPGConfig(**{**SMALL.to_dict(), "n_step": 4, "hidden_sizes": (16,)})
    agent = DDPG(GRID, ACCEL, config, seed=3)
    rng = np.random.default_rng(2)
    agent.episode_start()
    for _ in range(6):
        o = rng.uniform(0, 1, GRID.shape).astype(np.float32)
        agent.observe(o, agent.act(o), 0.1, o, terminated=False)
    agent.save(tmp_path / "a.pt", include_buffer=True)
    restored = DDPG(GRID, ACCEL, config, seed=99)
    restored.restore(tmp_path / "a.pt")
    assert len(restored._n_step) == len(agent._n_step) == 3
    restored.episode_start()
    agent.episode_start()
    np.testing.assert_array_equal(restored.buffer.horizons[:6], agent.buffer.horizons[:6])

    # A checkpoint written before these options existed: its config lacks their keys,
    # and its agent ran with one-step targets and fresh warm-up actions every step.
    legacy = {"n_step": 1, "warmup_hold_steps": 1.0, "hidden_sizes": (16,)}
    plain = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), **legacy}))
    plain.save(tmp_path / "old.pt")
    data = torch.load(tmp_path / "old.pt", weights_only=True)
    for key in ("n_step", "warmup_hold_steps", "preactivation_l2"):
        del data["config"][key]
    del data["n_step"], data["warmup_action"]
    torch.save(data, tmp_path / "old.pt")
    plain.restore(tmp_path / "old.pt")
    rebuilt = DDPG.from_checkpoint(tmp_path / "old.pt", GRID, ACCEL)
    assert (rebuilt.config.n_step, rebuilt.config.warmup_hold_steps) == (1, 1.0)
    with pytest.raises(CheckpointError, match="n_step"):  # not today's default agent
        DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), "hidden_sizes": (16,)})).restore(
            tmp_path / "old.pt"
        )


def test_n_step_over_transitions_that_span_several_steps():
    acc = NStepAccumulator(2, gamma=0.5)
    assert acc.push(_obs(0), _obs(0), 1.0, _obs(3), False, horizon=3) == []
    (first,) = acc.push(_obs(3), _obs(0), 4.0, _obs(5), False, horizon=2)
    # 1 + 0.5**3 * 4: the second reward comes 3 steps after the first
    assert first.reward == pytest.approx(1.5) and first.horizon == 5


def test_action_repeat_holds_each_action_and_stores_one_transition_per_hold():
    options = {"action_repeat": 3, "n_step": 1, "learning_starts": 0, "hidden_sizes": (16,)}
    agent = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), **options}), seed=1)
    rng = np.random.default_rng(3)
    frames = [rng.uniform(0, 1, GRID.shape).astype(np.float32) for _ in range(9)]
    agent.episode_start()
    actions = []
    for t in range(7):
        action = agent.act(frames[t])
        actions.append(float(action[0]))
        agent.observe(frames[t], action, 1.0, frames[t + 1], terminated=False)
    assert actions[0] == actions[1] == actions[2] and actions[3] == actions[4] == actions[5]
    assert actions[2] != actions[3]  # the noise moves on at the next decision
    assert len(agent.buffer) == 2 and agent.num_env_steps == 7
    assert agent.buffer.horizons[:2].tolist() == [3, 3]
    assert agent.buffer.rewards[0] == pytest.approx(1 + 0.99 + 0.99**2)
    np.testing.assert_array_equal(agent.buffer._obs.dense(np.array([1]))[0], frames[3].ravel())
    np.testing.assert_array_equal(agent.buffer._next_obs.dense(np.array([1]))[0], frames[6].ravel())
    # A time limit cuts the third hold after one step: it bootstraps from there.
    agent.episode_start()
    assert len(agent.buffer) == 3 and agent.buffer.horizons[2] == 1
    assert agent.buffer.terminated[2] == 0
    # A termination mid-hold ends the transition there, terminal.
    agent.act(frames[0])
    agent.observe(frames[0], np.array([0.2], np.float32), -10.0, frames[1], terminated=True)
    assert len(agent.buffer) == 4 and agent.buffer.terminated[3] == 1
    assert agent.buffer.horizons[3] == 1


def test_action_repeat_holds_the_deterministic_policy_too_and_restarts_each_episode():
    options = {"action_repeat": 4, "hidden_sizes": (16,)}
    agent = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), **options}), seed=2)
    rng = np.random.default_rng(4)
    frames = [rng.uniform(0, 1, GRID.shape).astype(np.float32) for _ in range(6)]
    agent.episode_start()
    chosen = [float(agent.act(frame, explore=False)[0]) for frame in frames[:5]]
    assert chosen[:4] == [chosen[0]] * 4 and chosen[4] != chosen[0]
    agent.episode_start()  # a new episode decides at once, on its own first frame
    assert float(agent.act(frames[5], explore=False)[0]) != chosen[4]


def test_a_held_action_survives_a_checkpoint(tmp_path: Path):
    options = {"action_repeat": 3, "n_step": 1, "learning_starts": 0, "hidden_sizes": (16,)}
    config = DDPGConfig(**{**SMALL.to_dict(), **options})
    agent = DDPG(GRID, ACCEL, config, seed=5)
    rng = np.random.default_rng(6)
    frames = [rng.uniform(0, 1, GRID.shape).astype(np.float32) for _ in range(8)]
    agent.episode_start()
    for t in range(4):  # one hold done, the second one step in
        agent.observe(frames[t], agent.act(frames[t]), 0.5, frames[t + 1], False)
    agent.save(tmp_path / "a.pt", include_buffer=True)
    restored = DDPG.from_checkpoint(tmp_path / "a.pt", GRID, ACCEL)
    for t in range(4, 7):
        a, b = agent.act(frames[t]), restored.act(frames[t])
        np.testing.assert_array_equal(a, b)
        agent.observe(frames[t], a, 0.5, frames[t + 1], False)
        restored.observe(frames[t], b, 0.5, frames[t + 1], False)
    assert len(agent.buffer) == len(restored.buffer) == 2
    assert agent.buffer.rewards[1] == restored.buffer.rewards[1]


def test_a_rule_driven_warm_up_follows_the_rule_with_perturbations():
    options = {"warmup_policy": "gap_acceptance", "learning_starts": 50, "hidden_sizes": (16,)}
    agent = DDPG(GRID, ACCEL, DDPGConfig(**{**SMALL.to_dict(), **options}), seed=7)
    obs = np.zeros(GRID.shape, np.float32)
    with pytest.raises(RuntimeError, match="set_warmup_policy"):
        agent.act(obs)
    agent.set_warmup_policy(lambda observation: np.array([-1.0], np.float32))
    actions = np.array([agent.act(obs)[0] for _ in range(50)])
    # -1 + N(0, 0.3) clipped to [-1, 1]: -1 + 0.3 E[max(Z, 0)] = -0.88 on average
    assert actions.max() < 0 and actions.mean() == pytest.approx(-0.88, abs=0.06)
    assert np.isnan(agent.last_policy_action).all()
    for _ in range(50):
        agent.observe(obs, np.zeros(1), 0.0, obs, False)
    agent.act(obs)  # past learning_starts: the policy, not the rule
    assert not np.isnan(agent.last_policy_action).any()


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("n_step", 0),
        ("warmup_hold_steps", 0.5),
        ("preactivation_l2", -1.0),
        ("action_repeat", 0),
        ("warmup_policy", "oracle"),
        ("terminal_fraction", 1.0),
        ("policy_delay", 0),
        ("target_noise", -0.1),
        ("critic_layer_norm", "yes"),
    ],
)
def test_bad_option_values_fail_clearly(field, value):
    with pytest.raises(ValueError, match=field):
        DDPGConfig(**{field: value})


def td3(**options: object) -> DDPGConfig:
    base = {"hidden_sizes": (16,), "n_step": 1, "learning_starts": 4, "batch_size": 4}
    return DDPGConfig(**{**SMALL.to_dict(), **base, **options})


def feed(agent: DDPG, steps: int, seed: int = 0) -> list[dict[str, float]]:
    rng = np.random.default_rng(seed)
    losses = []
    agent.episode_start()
    for t in range(steps):
        o, o2 = (rng.uniform(0, 1, GRID.shape).astype(np.float32) for _ in range(2))
        agent.observe(o, agent.act(o), float(rng.normal()), o2, terminated=t % 5 == 4)
        losses.append(agent.update())
    return losses


def test_twin_critics_learn_towards_the_smaller_target():
    agent = DDPG(GRID, ACCEL, td3(twin_critics=True), seed=4)
    state = agent.federated_state()
    assert {"critic2.layers.0.weight", "critic2_target.layers.0.weight"} <= set(state)
    assert not torch.equal(state["critic.layers.0.weight"], state["critic2.layers.0.weight"])
    feed(agent, 4)
    batch = agent.buffer.gather(np.arange(4), sparse=agent.sparse)
    with torch.no_grad():
        next_action = agent.actor_target(batch.next_obs)
        q1 = agent.critic_target(batch.next_obs, next_action)
        q2 = agent.critic2_target(batch.next_obs, next_action)
        target = batch.rewards + 0.99 * (1 - batch.terminated) * torch.minimum(q1, q2)
        expected = float(
            ((agent.critic(batch.obs, batch.actions) - target) ** 2).mean()
            + ((agent.critic2(batch.obs, batch.actions) - target) ** 2).mean()
        )
    assert agent._train_step(batch)["critic_loss"].item() == pytest.approx(expected, rel=1e-5)


def test_the_policy_and_the_targets_move_every_policy_delay_th_update():
    agent = DDPG(GRID, ACCEL, td3(policy_delay=3), seed=5)
    losses = feed(agent, 4)  # the first update
    actor_before = agent.actor.layers[0].bias.clone()
    target_before = agent.critic_target.layers[0].bias.clone()
    for _ in range(2):  # updates 2 and 3: critic only
        assert "actor_loss" not in feed(agent, 1)[0]
    assert torch.equal(agent.actor.layers[0].bias, actor_before)
    assert torch.equal(agent.critic_target.layers[0].bias, target_before)
    assert "actor_loss" in feed(agent, 1)[0]  # update 4 = 1 + 3
    assert not torch.equal(agent.actor.layers[0].bias, actor_before)
    assert "actor_loss" in losses[-1]


def test_target_policy_smoothing_is_clipped_gaussian_noise():
    agent = DDPG(GRID, ACCEL, td3(target_noise=0.2, target_noise_clip=0.3), seed=6)
    action = torch.zeros(20_000, 1)
    noise = agent._smoothed(action)
    assert noise.abs().max() <= 0.3 + 1e-6 and noise.std() == pytest.approx(0.17, abs=0.01)
    near_bound = agent._smoothed(torch.full((1000, 1), 0.9))
    assert near_bound.max() == 1.0 and near_bound.min() >= 0.6 - 1e-6  # within the range
    assert DDPG(GRID, ACCEL, td3(), seed=6)._smoothed(action) is action  # off: DDPG


def test_a_td3_agent_resumes_exactly(tmp_path: Path):
    config = td3(twin_critics=True, target_noise=0.2, policy_delay=2)
    agent = DDPG(GRID, ACCEL, config, seed=8)
    feed(agent, 10)
    agent.save(tmp_path / "td3.pt", include_buffer=True)
    restored = DDPG.from_checkpoint(tmp_path / "td3.pt", GRID, ACCEL)
    assert feed(agent, 6, seed=1) == feed(restored, 6, seed=1)
    a, b = agent.federated_state(), restored.federated_state()
    assert all(torch.equal(a[key], b[key]) for key in a)


def test_exploration_stretches_replace_the_noisy_policy_for_held_uniform_actions():
    options = {"explore_hold_probability": 0.1, "warmup_hold_steps": 5.0, "learning_starts": 0}
    agent = DDPG(GRID, ACCEL, td3(**options), seed=9)
    obs = np.zeros(GRID.shape, np.float32)
    policy = float(agent.act(obs, explore=False)[0])

    def drive(agent: DDPG, episodes: int) -> np.ndarray:
        actions = []
        for _ in range(episodes):  # 40-step episodes: OU noise stays within ~0.2
            agent.episode_start()
            actions += [float(agent.act(obs)[0]) for _ in range(40)]
        return np.array(actions)

    actions = drive(agent, 75)
    off_policy = np.abs(actions - policy) > 0.35
    # Stretches of ~5 decisions, one starting with chance 0.1 per other decision: about a
    # third of the decisions, of which uniform draws land off the policy ~2/3 of the time.
    assert 0.15 < off_policy.mean() < 0.32
    stays = off_policy[1:] & off_policy[:-1]
    assert (actions[1:][stays] == actions[:-1][stays]).mean() > 0.8  # a stretch holds
    # Off by default: the same seed then explores with the OU noise only.
    plain = DDPG(GRID, ACCEL, td3(learning_starts=0), seed=9)
    assert np.abs(drive(plain, 10) - policy).max() < 0.6  # OU: std 0.2 at step 40


class SlopeCritic(torch.nn.Module):
    """Q(s, a) = slope * a: the critic's gradient dQ/da is ``slope`` everywhere."""

    def __init__(self, slope: float) -> None:
        super().__init__()
        self.slope = slope

    def forward(self, obs: object, action: torch.Tensor) -> torch.Tensor:
        return self.slope * action.squeeze(-1)


def test_inverting_gradients_scale_dq_da_by_the_room_left_and_turn_round_past_a_bound():
    agent = DDPG(GRID, ACCEL, td3(actor_update="inverting_gradients"), seed=10)
    assert agent.actor.output == agent.actor_target.output == "clip"
    feed(agent, 4)
    batch = agent.buffer.gather(np.arange(4), sparse=agent.sparse)
    agent.critic = SlopeCritic(-2.0)  # the critic asks for less everywhere
    with torch.no_grad():
        agent.actor.layers[-1].bias.fill_(1.5)  # past the upper bound
        p = agent.actor.preactivation(batch.obs).squeeze(-1)
    agent.actor_optimizer.zero_grad()
    agent._inverting_gradients_loss(batch)[0].backward()
    # d(surrogate)/d(bias) = mean of -(dQ/da) * (p + 1) / 2 = mean of (p + 1)
    expected = float((p + 1.0).mean())
    assert agent.actor.layers[-1].bias.grad.item() == pytest.approx(expected, rel=1e-5)
    for _ in range(300):  # comes back from past +1 and settles at the lower bound
        agent._actor_step(batch)
    with torch.no_grad():
        actions = agent.actor(batch.obs)
        p = agent.actor.preactivation(batch.obs)
    assert torch.all(actions < -0.9) and torch.all(p > -1.2)


def test_a_layer_norm_critic_normalises_every_hidden_layer_and_leaves_the_actor_alone():
    config = td3(hidden_sizes=(16, 8), critic_layer_norm=True, twin_critics=True)
    agent = DDPG(GRID, ACCEL, config, seed=10)
    state = agent.federated_state()
    for critic in ("critic", "critic_target", "critic2", "critic2_target"):
        assert torch.equal(state[f"{critic}.norms.0.weight"], torch.ones(16))
        assert torch.equal(state[f"{critic}.norms.1.bias"], torch.zeros(8))
    assert not any(".norms." in key for key in state if key.startswith("actor"))
    plain = DDPG(GRID, ACCEL, td3(hidden_sizes=(16, 8)), seed=10)
    assert not any(".norms." in key for key in plain.federated_state())
    # The same initial weights; only the normalisation differs.
    assert torch.equal(state["critic.layers.1.weight"], plain.critic.layers[1].weight)
    seen: list[torch.Tensor] = []
    norm = agent.critic.norms[1]
    handle = norm.register_forward_hook(lambda module, args, output: seen.append(output.clone()))
    obs = torch.from_numpy(np.random.default_rng(0).uniform(0, 1, (5, *GRID.shape)))
    with torch.no_grad():
        agent.critic(obs.reshape(5, -1).float(), torch.zeros(5, 1))
    handle.remove()
    (hidden,) = seen
    assert hidden.mean(dim=1).abs().max() < 1e-5
    assert hidden.std(dim=1, unbiased=False) == pytest.approx(torch.ones(5), abs=1e-3)
    feed(agent, 8)  # the norms learn like every other critic weight
    assert not torch.equal(agent.critic.norms[0].weight, torch.ones(16))


def test_a_layer_norm_critic_resumes_exactly_and_old_checkpoints_load_without_it(tmp_path: Path):
    agent = DDPG(GRID, ACCEL, td3(critic_layer_norm=True), seed=11)
    feed(agent, 10)
    agent.save(tmp_path / "ln.pt", include_buffer=True)
    restored = DDPG.from_checkpoint(tmp_path / "ln.pt", GRID, ACCEL)
    assert restored.config.critic_layer_norm
    assert feed(agent, 6, seed=1) == feed(restored, 6, seed=1)
    plain = DDPG(GRID, ACCEL, td3(), seed=11)
    plain.save(tmp_path / "old.pt")
    data = torch.load(tmp_path / "old.pt", weights_only=True)
    del data["config"]["critic_layer_norm"]
    torch.save(data, tmp_path / "old.pt")
    assert not DDPG.from_checkpoint(tmp_path / "old.pt", GRID, ACCEL).config.critic_layer_norm
