"""``train(cfg)`` end to end for each scheme on tiny networks, in-process, plus resume
after a kill, a worker killed mid-run, and one subprocess multirun."""

import json
import multiprocessing
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from train_helpers import compose_config

from frl.agents import DDPG
from frl.federation import ClientFailure
from frl.federation.tensorboard import EPISODE_WINDOW
from frl.report.aggregate import reward_curve
from frl.report.runs import load_run
from frl.train import train

RESULT_KEYS = {
    "scheme", "seed", "interval", "total_steps", "tasks", "clients", "rounds",
    "communication", "training", "evaluation", "versions", "run_dir",
}  # fmt: skip
COMMUNICATION_KEYS = {
    "aggregation", "targets", "bytes_per_upload", "bytes_per_download", "uploads",
    "downloads", "total_bytes_up", "total_bytes_down", "total_bytes",
}  # fmt: skip
METRIC_KEYS = {
    "average_reward", "collision_rate", "arrival_rate", "timeout_rate",
    "average_travel_time", "average_episode_steps", "episodes",
}  # fmt: skip


def _scalar_tags(run_dir: Path) -> dict[str, list]:
    accumulator = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    accumulator.Reload()
    return {tag: accumulator.Scalars(tag) for tag in accumulator.Tags()["scalars"]}


@pytest.mark.parametrize("scheme", ["central", "separate", "fedavg"])
def test_each_scheme_trains_logs_and_tests(scheme, tmp_path, capsys):
    cfg = compose_config(tmp_path / "run", [f"federation={scheme}"])

    results = train(cfg)

    run_dir = tmp_path / "run"
    saved = json.loads((run_dir / "results.json").read_text())
    assert saved == json.loads(json.dumps(results))
    assert set(saved) >= RESULT_KEYS
    assert saved["rounds"] == 3 and saved["training"]["steps_per_client"] == 240
    clients = ["client0_random"] if scheme == "central" else [
        "client0_left", "client1_straight", "client2_right"
    ]  # fmt: skip
    assert saved["clients"] == clients
    assert all(saved["training"]["episodes"][c] >= 1 for c in clients)
    # The default collision budget's end state, per vehicle, from its rounds' episodes.
    budget = saved["training"]["collision_budget"]
    assert list(budget) == clients
    for client in clients:
        assert len(budget[client]["multiplier_per_round"]) == 3
        last_rate = budget[client]["collision_rate_per_round"][-1]
        assert budget[client]["last_round_collision_rate"] == last_rate
        assert budget[client]["kept"] == (last_rate <= 1.5 * 0.02)
    communication = saved["communication"]
    assert set(communication) == COMMUNICATION_KEYS
    if scheme == "fedavg":
        assert communication["uploads"] == 3 * 3
        assert communication["bytes_per_upload"] > 0
        assert communication["total_bytes_up"] == 9 * communication["bytes_per_upload"]
        assert communication["total_bytes_down"] == 9 * communication["bytes_per_download"]
    else:
        assert communication["total_bytes"] == 0
    evaluation = saved["evaluation"]
    assert set(evaluation["per_task"]) == {"left", "straight", "right"}
    for metrics in evaluation["per_task"].values():
        assert set(metrics) == METRIC_KEYS | {"return_std"}  # per task: for intervals
    assert set(evaluation["average"]) == METRIC_KEYS
    assert evaluation["per_task"]["left"]["episodes"] == 2
    assert "travel_time_definition" in evaluation
    assert evaluation["traffic"] == "paper"
    assert list(evaluation["yardsticks"]) == [
        "full_throttle",
        "gap_acceptance",
        "committed_gap_acceptance",
        "oracle",
    ]
    for table in evaluation["yardsticks"].values():
        assert set(table["per_task"]) == set(evaluation["per_task"])
        assert table["per_task"]["left"]["episodes"] == 2
    assert evaluation["yardsticks"]["oracle"]["average"]["collision_rate"] == 0.0
    printed = capsys.readouterr().out
    assert "full throttle (same seeds)" in printed and "oracle (same seeds)" in printed
    assert {"frl", "torch", "sumo", "python"} <= set(saved["versions"])

    for name in ("config.yaml", "versions.json", "state.json", "models/index.json"):
        assert (run_dir / name).exists(), name
    assert not any((run_dir / "checkpoints").iterdir())  # buffers dropped once models exist

    tags = _scalar_tags(run_dir)
    every_step = np.load(run_dir / "step_rewards.npy")
    assert every_step.shape == (240,)
    # TensorBoard: a mean per window, windows of 100 steps cut at each round's end (80).
    assert [e.step for e in tags["train/step_reward"]] == [80, 160, 240]
    means = every_step.reshape(3, 80).mean(axis=1)
    assert [e.value for e in tags["train/step_reward"]] == pytest.approx(means, rel=1e-6)
    assert [e.step for e in tags["server/round"]] == [80, 160, 240]
    fig4 = reward_curve(load_run(run_dir), EPISODE_WINDOW)  # the report's Fig. 4 curve
    assert tags["rollout/ep_rew_mean"][-1].value == pytest.approx(fig4[-1], abs=1e-4)
    assert saved["training"]["final_ep_rew_mean"] == pytest.approx(fig4[-1], abs=1e-4)
    for tag in ("server/bytes_up", "server/bytes_down", "server/bytes_total"):
        assert tag in tags
    for client in clients:
        for name in ("episode_return", "episode_collision", "episode_travel_time_steps"):
            assert f"{client}/{name}" in tags
        assert f"{client}/critic_loss" in tags and f"{client}/actor_loss" in tags
        for name in (
            "td_error",
            "episode_mean_speed",
            "episode_stopped_steps",
            "action_at_bounds",
            "policy_action_at_bounds",
            "policy_action_mean",
        ):
            assert f"{client}/{name}" in tags, name  # fmt: skip
    for group in ("left", "straight", "right", "average"):
        assert f"eval/{group}/average_reward" in tags
        assert f"eval/{group}/collision_rate" in tags
        assert f"eval_yardstick/oracle/{group}/collision_rate" in tags
    hparams = EventAccumulator(str(run_dir / "tb"))
    hparams.Reload()
    assert "_hparams_/experiment" in hparams.PluginTagToContent("hparams")


class _Killed(Exception):
    pass


def test_resume_after_a_kill_finishes_the_budget(tmp_path):
    overrides = [
        "federation=fedavg", "federation.tasks=[left,right]", "eval_episodes=0",
        "round_test_episodes=1",
    ]  # fmt: skip
    cfg = compose_config(tmp_path / "run", overrides)

    def kill_after_round(state):
        if state.completed_rounds == 2:
            raise _Killed

    with pytest.raises(_Killed):
        train(cfg, on_round_end=kill_after_round)
    assert multiprocessing.active_children() == []
    state = json.loads((tmp_path / "run" / "state.json").read_text())
    assert state["completed_rounds"] == 2 and not state["training_finished"]
    # Saved as frl saved configs before interval counted updates (format 1): rounds of 80
    # environment steps, no config_version. It resumes as the same rounds.
    config_path = tmp_path / "run" / "config.yaml"
    saved = yaml.safe_load(config_path.read_text())
    assert (saved.pop("config_version"), saved["interval"]) == (2, 40)
    config_path.write_text(yaml.safe_dump({**saved, "interval": 80}))

    rounds_seen = []
    results = train(  # on another share of the cores: the resuming machine's
        compose_config(tmp_path / "run", [*overrides, "resume=true", "cores=1"]),
        on_round_end=lambda s: rounds_seen.append(s.completed_rounds),
    )

    assert rounds_seen == [3]  # only the missing round ran
    resaved = yaml.safe_load(config_path.read_text())
    assert (resaved["cores"], resaved["interval"], resaved["config_version"]) == (1, 40, 2)
    assert results["rounds"] == 3
    assert results["training"]["steps_per_client"] == 240
    assert results["communication"]["uploads"] == 2 * 3
    assert len(np.load(tmp_path / "run" / "step_rewards.npy")) == 240
    tags = _scalar_tags(tmp_path / "run")
    assert [e.step for e in tags["server/round"]] == [80, 160, 240]
    # The per-round test curve went on too, its points before the kill kept
    assert [p["step"] for p in results["round_tests"]["points"]] == [80, 160, 240]
    assert [e.step for e in tags["eval/round/average/average_reward"]] == [80, 160, 240]
    # Fig. 4's windows went on over the resume: TensorBoard and results.json end on the
    # report's curve, computed from every episode of both sessions
    fig4 = reward_curve(load_run(tmp_path / "run"), EPISODE_WINDOW)
    assert tags["rollout/ep_rew_mean"][-1].value == pytest.approx(fig4[-1], abs=1e-4)
    assert results["training"]["final_ep_rew_mean"] == pytest.approx(fig4[-1], abs=1e-4)


def test_a_worker_killed_mid_run_stops_the_run_naming_the_client(tmp_path):
    cfg = compose_config(tmp_path / "run", ["federation=separate", "federation.tasks=[left,right]"])

    def kill_a_worker(state):
        victim = next(p for p in multiprocessing.active_children() if "client1_right" in p.name)
        os.kill(victim.pid, signal.SIGKILL)

    with pytest.raises(ClientFailure, match="client client1_right failed") as info:
        train(cfg, on_round_end=kill_a_worker)
    assert "SIGKILL" in str(info.value)
    assert multiprocessing.active_children() == []


def test_multirun_over_two_seeds_in_a_subprocess(tmp_path):
    sweep = tmp_path / "sweep"
    overrides = [
        o for o in compose_config.__globals__["TINY_OVERRIDES"] if not o.startswith("progress")
    ]
    command = [
        sys.executable, "-m", "frl.train", "-m", "seed=0,1",
        "federation=central", "federation.tasks=[left]", *overrides, "eval_episodes=0",
        f"hydra.sweep.dir={sweep}",
    ]  # fmt: skip
    env = {**os.environ, "HYDRA_FULL_ERROR": "1"}
    # A guard against a hang, not a speed target: the two jobs took 257 s on a 2-core
    # machine busy with a training run, and more than 300 s beside two.
    done = subprocess.run(
        command, cwd=Path(__file__).resolve().parents[1], env=env,
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and (p / "results.json").exists())
    assert len(jobs) == 2
    seeds = [json.loads((job / "results.json").read_text())["seed"] for job in jobs]
    assert sorted(seeds) == [0, 1]
    for job in jobs:
        assert (job / ".hydra" / "config.yaml").exists()
        assert any((job / "tb").iterdir())
        assert (job / "figure.png").read_bytes().startswith(b"\x89PNG")  # frl.plot's picture
    assert "step/s" not in done.stderr  # no progress bar in multirun


def test_a_guided_route_observing_agent_trains_and_tests(tmp_path):
    """The learning options of the driver study through the whole pipeline: a teacher
    installed in every vehicle and Dict observations in the vehicles' agents."""
    overrides = [
        "agent=ddpg-guided", "env.route_observation=true", "agent.encoder=vehicles",
        "yardsticks=[gap_acceptance]",
    ]  # fmt: skip
    cfg = compose_config(tmp_path / "run", overrides)
    results = train(cfg)
    tags = _scalar_tags(tmp_path / "run")
    assert "client1_straight/imitation_loss" in tags
    evaluation = results["evaluation"]
    assert evaluation["average"]["episodes"] == 6
    rule = evaluation["yardsticks"]["gap_acceptance"]["average"]
    assert rule["episodes"] == 6
    model = DDPG.load(next((tmp_path / "run" / "models").glob("*.pt")))
    assert model.config.guided and model.layout.parts == {"grid": (26, 18, 3), "route": (4,)}
