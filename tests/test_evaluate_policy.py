"""evaluate_policy: any driver on frl's test protocol, beside the yardsticks."""

import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import frl.envs  # noqa: F401 (registers frl/Intersection-v0)
from frl.agents import DDPG, DDPGConfig
from frl.envs import TASKS, EnvConfig, IntersectionEnv
from frl.evaluate import evaluate_policy, evaluate_yardsticks
from frl.policies import GapAcceptancePolicy

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_a_callable_gets_exactly_the_table_frl_evaluate_gives_its_yardstick():
    ours = evaluate_policy(
        GapAcceptancePolicy(EnvConfig()), episodes=2, yardsticks=("full_throttle",), verbose=False
    )
    theirs = evaluate_yardsticks(["gap_acceptance"], list(TASKS), seed=0, episodes=2)
    assert ours["per_task"] == theirs["gap_acceptance"]["per_task"]
    assert ours["average"] == theirs["gap_acceptance"]["average"]
    assert list(ours["yardsticks"]) == ["full_throttle"]
    assert ours["yardsticks"]["full_throttle"]["per_task"]["left"]["episodes"] == 2


def test_an_object_with_predict_is_scored_like_its_predict(capsys):
    env = IntersectionEnv()
    agent = DDPG(env.observation_space, env.action_space, DDPGConfig(hidden_sizes=(16,)), seed=1)
    env.close()

    scored = evaluate_policy(agent, episodes=1, tasks=["right"], yardsticks=())
    by_hand = evaluate_policy(
        lambda obs: agent.predict(obs)[0], episodes=1, tasks=["right"], yardsticks=(),
        verbose=False,
    )  # fmt: skip
    assert scored["per_task"] == by_hand["per_task"]
    assert "policy, seed 0: 1 test episodes per task" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"traffic": "rush"}, "unknown traffic preset 'rush'"),
        ({"seed": -1}, "seed must be a non-negative integer"),
        ({"episodes": 0}, "episodes must be a positive integer"),
        ({"tasks": ["uturn"]}, "unknown task 'uturn'"),
        ({"yardsticks": ["bogus"]}, "unknown yardstick 'bogus'"),
    ],
)
def test_bad_input_fails_before_any_episode(kwargs, message):
    calls = []
    with pytest.raises(ValueError, match=message):
        evaluate_policy(lambda obs: calls.append(obs) or np.ones(1), verbose=False, **kwargs)
    assert calls == []


def test_something_that_cannot_act_is_refused():
    with pytest.raises(ValueError, match="policy must be a callable"):
        evaluate_policy(42, verbose=False)


def test_a_stable_baselines3_td3_trains_on_the_env_and_is_scored():
    stable_baselines3 = pytest.importorskip("stable_baselines3")
    env = gym.make("frl/Intersection-v0", task="left")
    model = stable_baselines3.TD3(
        "MlpPolicy", env, learning_starts=50, batch_size=32, policy_kwargs={"net_arch": [32]},
        seed=0,
    )  # fmt: skip
    model.learn(total_timesteps=120)
    env.close()  # libsumo: one simulation per process, so the test's SUMO starts after

    scored = evaluate_policy(model, episodes=2, tasks=["left"], yardsticks=("full_throttle",))
    assert scored["per_task"]["left"]["episodes"] == 2
    assert set(scored["yardsticks"]) == {"full_throttle"}


PLAIN_SCRIPT = """
import numpy as np
from frl.evaluate import evaluate_policy

table = evaluate_policy(lambda o: np.array([1.0], np.float32), episodes=2)
print("average return", table["average"]["average_reward"])
"""


def test_the_readme_call_works_in_a_plain_script_without_a_main_guard(tmp_path):
    """The yardsticks run in spawned workers; they must not run the caller's script again."""
    script = tmp_path / "score.py"
    script.write_text(PLAIN_SCRIPT)
    # An empty cache: every yardstick runs, in worker processes.
    env = {**os.environ, "FRL_CACHE_DIR": str(tmp_path / "cache")}
    result = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    assert result.stdout.count("average return") == 1  # the script ran once, not per worker
    assert "oracle (same seeds)" in result.stdout
