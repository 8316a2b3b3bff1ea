"""``agent.bang_bang``: every action the agent executes lies at a bound, the buffer holds
the executed action, and the TD target reads the target actor's executed one."""

import numpy as np
import pytest
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig
from frl.agents.acting import ActionScale

GRID = spaces.Box(-2.0, 2.0, (26, 18, 3), dtype=np.float32)
# Asymmetric bounds: the executed actions are the bounds, not +-1 in the env's units.
ACCEL = spaces.Box(-2.0, 3.0, (1,), dtype=np.float32)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def config(bang_bang: bool) -> DDPGConfig:
    return DDPGConfig(
        hidden_sizes=(16,), buffer_size=200, learning_starts=20, batch_size=8, n_step=1,
        bang_bang=bang_bang,
    )  # fmt: skip


def drive(agent: DDPG, steps: int) -> list[float]:
    """Explore ``steps`` steps on random grids (warm-up, then the policy plus noise),
    updating as due; the env actions taken."""
    rng = np.random.default_rng(0)
    taken = []
    agent.episode_start()
    for t in range(steps):
        obs, next_obs = (rng.uniform(0, 1, GRID.shape).astype(np.float32) for _ in range(2))
        action = agent.act(obs)
        taken.append(float(action[0]))
        agent.observe(obs, action, float(rng.normal()), next_obs, terminated=t % 7 == 6)
        agent.update()
    return taken


def test_every_executed_action_is_a_bound_and_is_stored_as_one():
    agent = DDPG(GRID, ACCEL, config(True), seed=0)
    taken = drive(agent, 60)  # 20 warm-up steps, then 40 exploring ones with updates
    assert set(taken) <= {-2.0, 3.0} and len(set(taken)) == 2
    stored = agent.buffer.actions[: len(agent.buffer), 0]
    assert set(np.unique(stored)) == {-1.0, 1.0}
    grids = np.random.default_rng(1).uniform(0, 1, (5, *GRID.shape)).astype(np.float32)
    tested = [float(agent.act(grid, explore=False)[0]) for grid in grids]
    assert set(tested) <= {-2.0, 3.0}
    batch, _ = agent.predict(grids)
    assert batch[:, 0].tolist() == tested


def test_the_td_target_reads_the_executed_next_action_and_only_with_the_option():
    for bang_bang in (True, False):
        agent = DDPG(GRID, ACCEL, config(bang_bang), seed=0)
        drive(agent, 40)
        slots = agent.buffer.sample_slots(agent.config.batch_size)
        batch = agent.buffer.gather(slots, agent.sparse, agent.device, False)
        next_actions = agent.critic_losses(batch).next_actions.abs()
        if bang_bang:
            assert (next_actions == 1).all()
        else:  # the actor's own actions lie inside the bounds
            assert (next_actions < 1).all()


def test_without_the_option_the_action_passes_as_it_is():
    plain, bang = ActionScale(ACCEL), ActionScale(ACCEL, bang_bang=True)
    half = np.array([0.2])
    assert plain.from_unit(half)[0] == pytest.approx(1.0)  # -2 + 1.2 / 2 * 5
    assert bang.from_unit(half)[0] == 3.0 and bang.from_unit(np.array([0.0]))[0] == -2.0


def test_a_bang_bang_agent_survives_a_checkpoint(tmp_path):
    agent = DDPG(GRID, ACCEL, config(True), seed=0)
    drive(agent, 30)
    agent.save(tmp_path / "agent.pt")
    loaded = DDPG.load(tmp_path / "agent.pt")
    assert loaded.config.bang_bang and loaded.scale.bang_bang
    grid = np.zeros(GRID.shape, np.float32)
    assert loaded.act(grid, explore=False)[0] == agent.act(grid, explore=False)[0]


@pytest.mark.parametrize("value", ["yes", 2, None])
def test_a_bang_bang_that_is_no_bool_fails_naming_the_key(value):
    with pytest.raises(ValueError, match="bang_bang"):
        DDPGConfig(bang_bang=value)
