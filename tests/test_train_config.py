"""Bad configurations fail fast, with clear messages, before any process starts."""

import multiprocessing
import re
import shutil
from pathlib import Path

import pytest
import yaml
from hydra.errors import ConfigCompositionException
from omegaconf.errors import ValidationError
from train_helpers import CONF_DIR, compose_config

from frl.federation.assembly import client_specs, worker_threads
from frl.federation.workers import available_cores
from frl.train import train
from frl.train_config import ConfigError, load_run_config, migrate_saved_config, validate


def test_the_default_config_is_fedavg_on_the_three_tasks():
    settings = validate(compose_config(None))
    default = validate(compose_config(None, []))
    assert settings == default
    cfg = compose_config(None, ["total_steps=10000", "interval=1000"])  # every 2 steps
    plan = validate(cfg).plan
    assert (plan.scheme, plan.num_rounds, plan.tasks) == (
        "fedavg",
        5,
        ("left", "straight", "right"),
    )


def test_the_main_command_trains_eight_steps_per_update_and_the_editions_one():
    from frl.training import schedule_line

    def full(overrides: list[str]):  # as python -m frl.train composes it, no tiny budget
        return validate(compose_config(None, overrides, tiny=False))

    settings = full([])
    assert (settings.plan.total_steps, settings.plan.interval) == (80_000, 16_000)
    assert settings.agent.train_freq == 8
    # The command frl is known by is the default run: interval counts updates.
    assert full(["federation=fedavg", "interval=2000"]) == settings
    line = schedule_line(settings.plan, settings.agent)
    assert line.startswith(
        "fedavg, 3 vehicles (left, straight, right): 5 rounds of 2,000 updates per vehicle "
        "(16,000 environment steps; models averaged after each), 80,000 environment steps "
        "and 9,876 updates per vehicle, an update every 8 steps; none in the first 1,000 "
        "steps (the warm-up), so the first round has 1,876"
    )
    paper = full(["budget=paper"])
    assert (paper.plan.total_steps, paper.plan.interval, paper.agent.train_freq) == (
        10_000, 2_000, 1,
    )  # fmt: skip
    # The default budget trains under a collision budget; the paper's, as the paper, not.
    assert (settings.agent.collision_budget, paper.agent.collision_budget) == (0.02, None)
    # Its cost critic learns each episode's costs to go; the guided preset keeps the n-step
    # target it was measured with.
    assert settings.agent.costs_to_go and not paper.agent.costs_to_go
    guided = full(["+experiment=guided-committed"]).agent
    assert (guided.collision_budget, guided.cost_target) == (0.02, "n_step")
    # Its critics learn at 3e-4; the paper's budget and the guided preset keep Table II's
    # 1e-4, what their runs were measured with.
    assert (settings.agent.critic_lr, paper.agent.critic_lr, guided.critic_lr) == (
        3e-4, 1e-4, 1e-4,
    )  # fmt: skip
    assert settings.agent.actor_lr == paper.agent.actor_lr == 1e-4
    as_paper = ["agent.train_freq=1", "agent.collision_budget=null", "agent.critic_lr=0.0001"]
    assert paper.agent == full(as_paper).agent
    paper_line = schedule_line(paper.plan, paper.agent)
    assert "5 rounds of 2,000 updates per vehicle (2,000 environment steps" in paper_line
    assert "10,000 environment steps and 9,001 updates per vehicle" in paper_line
    for preset in ("fig3", "fig4", "fig4-guided", "fig6", "quick", "study-learning"):
        edition = full([f"+experiment={preset}"])
        assert edition.agent.train_freq == 1, preset
        assert edition.agent.collision_budget is None, preset  # the editions' runs, unchanged
        assert edition.agent.critic_lr == (1e-3 if preset == "quick" else 1e-4), preset
        assert edition.plan.total_steps == (3_000 if preset == "quick" else 10_000), preset
    assert full(["+experiment=fig6", "interval=500"]).plan.interval == 500
    assert full(["agent=ddpg-paper", "budget=paper"]).agent.train_freq == 1


@pytest.mark.parametrize(
    "preset", sorted(path.stem for path in (Path(CONF_DIR) / "experiment").glob("*.yaml"))
)
def test_every_experiment_preset_composes_and_validates(preset):
    validate(compose_config(None, [f"+experiment={preset}"]))


FASTER_LEARNING = ["agent.actor_lr=0.001", "agent.critic_lr=0.001", "agent.tau=0.005"]
"""The studies' learning variant: the quick preset's rates on Table II's networks."""


def test_the_learning_study_is_fig4s_central_ddpg_but_for_its_overrides():
    study = validate(compose_config(None, ["+experiment=study-learning", *FASTER_LEARNING]))
    fig4_central = ["federation=central", "budget=paper"]
    assert study == validate(compose_config(None, [*fig4_central, *FASTER_LEARNING]))
    assert study != validate(compose_config(None, fig4_central))
    assert study.plan.scheme == "central" and study.agent.actor_lr == 0.001


def test_the_waiting_study_is_the_learning_study_without_the_undisturbed_bonus():
    study = validate(compose_config(None, ["+experiment=study-waiting", *FASTER_LEARNING]))
    learning = validate(compose_config(None, ["+experiment=study-learning", *FASTER_LEARNING]))
    assert learning.reward.undisturbed_bonus > 0
    without_bonus = ["+experiment=study-learning", "reward.undisturbed_bonus=0", *FASTER_LEARNING]
    assert study == validate(compose_config(None, without_bonus))


@pytest.mark.parametrize(
    ("overrides", "shared"),
    [
        ([], True),  # FedAvg: the clients start from one initial global model
        (["federation=separate"], False),
        (["federation=central"], False),
        (["federation.initial_model=independent"], False),  # FedAvg from apart: an ablation
        (["federation=separate", "federation.initial_model=shared"], True),
        (["federation.initial_model=null"], True),  # null: the scheme's default
        (["federation=separate", "federation.initial_model=null"], False),
    ],
)
def test_which_clients_share_one_initial_model(overrides, shared):
    specs = client_specs(validate(compose_config(None, overrides)))
    init_seeds = {spec.init_seed for spec in specs}
    agent_seeds = {spec.agent_seed for spec in specs}
    assert len(agent_seeds) == len(specs)  # every client keeps its own streams
    if shared:
        assert len(init_seeds) == 1 and None not in init_seeds
    else:
        assert init_seeds == {None}


def test_the_shared_initial_model_depends_on_the_run_seed():
    seeds = [
        client_specs(validate(compose_config(None, [f"seed={s}"])))[0].init_seed for s in (0, 0, 1)
    ]
    assert seeds[0] == seeds[1] != seeds[2]


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["federation.scheme=fedsgd"], "unknown federation scheme 'fedsgd'"),
        (["interval=0"], r"interval counts the updates .* got 0"),
        (["interval=-5"], r"lie in \[1, 120\] \(total_steps=240 / agent.train_freq=2\), got -5"),
        (["interval=121"], r"lie in \[1, 120\] .* got 121"),
        (["interval=61", "agent.train_freq=4"], r"lie in \[1, 60\] .* got 61"),
        (["federation.tasks=[left,uturn]"], "unknown task 'uturn'"),
        (["reward.name=fancy"], "unknown reward 'fancy'"),
        (["federation.backend=grpc"], "unknown federation.backend 'grpc'"),
        (["agent.tau=2.0"], "tau must lie in"),
        (["env.max_episode_steps=0"], "max_episode_steps"),
        (["eval_episodes=-1"], "eval_episodes"),
        (["federation.initial_model=copied"], "initial_model must be one of shared, independent"),
        (["cores=-1"], r"cores must be >= 0 \(0: all \d+ available\), got -1"),
        ([f"cores={available_cores() + 1}"], r"exceeds the \d+ cores available"),
    ],
)
def test_bad_values_raise_config_error_before_any_process(overrides, message, tmp_path):
    cfg = compose_config(tmp_path / "run", overrides)
    with pytest.raises(ConfigError, match=message):
        train(cfg)
    assert multiprocessing.active_children() == []
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["interval=abc"], "could not be converted to Integer"),
        (["agent.lrr=1"], "Key 'lrr' not in 'AgentSchema'"),
        (["federation=bogus"], "federation/bogus"),
        (["reward=bogus"], "reward/bogus"),
    ],
)
def test_typos_and_wrong_types_fail_while_composing(overrides, message):
    with pytest.raises((ConfigCompositionException, ValidationError)) as info:
        compose_config(None, overrides)
    assert re.search(message, f"{info.value} {info.value.__cause__}")


@pytest.mark.parametrize(
    ("overrides", "workers", "threads"),
    [
        (["cores=1"], 1, 1),  # Central-DDPG's one worker on a one-core share
        (["cores=1"], 3, 1),  # never fewer than one thread a worker
        (["cores=1", "federation.threads_per_worker=2"], 3, 2),  # explicit threads win
    ],
)
def test_cores_split_over_a_runs_workers(overrides, workers, threads):
    assert worker_threads(validate(compose_config(None, overrides)), workers) == threads


def test_the_default_cores_are_every_available_core():
    settings = validate(compose_config(None, []))
    assert settings.cores is None
    assert worker_threads(settings, 1) == available_cores()


def test_resume_needs_a_run(tmp_path):
    cfg = compose_config(tmp_path / "run", [f"resume={tmp_path / 'nothing'}"])
    with pytest.raises(ConfigError, match="no checkpointed run there"):
        train(cfg)


def test_a_config_pickled_into_another_process_still_merges_with_the_schema():
    """A Hydra launcher (submitit, Ray) pickles the composed config into each job: the
    generated schema classes must arrive as themselves, not as copies OmegaConf refuses."""
    import pickle
    import subprocess
    import sys

    cfg = compose_config(None, ["seed=3"])
    script = (
        "import pickle, sys; from frl.train_config import validate; "
        "print(validate(pickle.loads(sys.stdin.buffer.read())).seed)"
    )
    result = subprocess.run(
        [sys.executable, "-c", script], input=pickle.dumps(cfg), capture_output=True, timeout=120
    )
    assert result.returncode == 0, result.stderr.decode()[-2000:]
    assert result.stdout.decode().strip() == "3"


@pytest.mark.parametrize(("train_freq", "learning_starts"), [(1, 10), (3, 10), (8, 1)])
def test_the_run_says_what_it_trains_and_counts_the_updates_an_agent_takes(
    train_freq, learning_starts
):
    import numpy as np
    from gymnasium import spaces

    from frl.agents import DDPG, DDPGConfig
    from frl.federation.plan import FederationPlan
    from frl.training import schedule_line

    config = DDPGConfig(
        hidden_sizes=(8,), batch_size=1, buffer_size=100, n_step=1,
        learning_starts=learning_starts, train_freq=train_freq,
    )  # fmt: skip
    box = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
    agent = DDPG(box, box, config)
    for _ in range(60):
        agent.observe(np.zeros(2), np.zeros(2), 0.0, np.zeros(2), False)
        agent.update()
    round_steps = 20 - 20 % train_freq
    plan = FederationPlan(total_steps=60, interval=round_steps)
    line = schedule_line(plan, config)
    assert f"60 environment steps and {agent.num_updates} updates per vehicle" in line
    assert line.startswith(
        f"fedavg, 3 vehicles (left, straight, right): {plan.num_rounds} rounds of "
        f"{round_steps // train_freq} updates per vehicle ({round_steps} environment steps"
    )
    first = DDPG(box, box, config)
    for _ in range(round_steps):
        first.observe(np.zeros(2), np.zeros(2), 0.0, np.zeros(2), False)
        first.update()
    assert line.endswith(f"so the first round has {first.num_updates}")
    fleet = schedule_line(FederationPlan(total_steps=60, interval=20, vehicles_per_task=3), config)
    assert fleet.startswith("fedavg, 9 vehicles (left, straight, right): ")


STUDY_DATA = Path(CONF_DIR).parents[1] / "docs" / "results" / "data"


@pytest.mark.parametrize(
    ("run", "rounds_of"),
    [("study-data/tf8/fedavg-seed0", 16_000), ("fig6/interval1000-seed0", 1_000)],
)
def test_runs_saved_with_interval_in_environment_steps_read_as_the_same_rounds(
    run, rounds_of, tmp_path
):
    saved = yaml.safe_load((STUDY_DATA / run / "config.yaml").read_text())
    assert "config_version" not in saved and saved["interval"] == rounds_of
    shutil.copy(STUDY_DATA / run / "config.yaml", tmp_path / "config.yaml")
    settings = validate(load_run_config(tmp_path), this_machine=False)
    assert settings.plan.interval == rounds_of  # environment steps, as it trained
    migrated = migrate_saved_config(saved)
    assert migrated["interval"] * settings.agent.train_freq == rounds_of
    assert migrated["config_version"] == 2


def test_a_saved_interval_that_is_no_whole_number_of_updates_is_refused(tmp_path):
    saved = yaml.safe_load((STUDY_DATA / "study-data/tf8/fedavg-seed0/config.yaml").read_text())
    with pytest.raises(ConfigError, match=r"not a whole number of updates at agent\.train_freq=8"):
        migrate_saved_config({**saved, "interval": 1_001})


def test_a_config_version_of_another_frl_is_refused():
    with pytest.raises(ConfigError, match="config_version=1 is not this frl's"):
        validate(compose_config(None, ["config_version=1"]))


def test_each_task_s_vehicles_get_their_own_collision_budget():
    budgets = "+agent.collision_budget_by_task={left:0.14,straight:0.08,right:0.02}"
    overrides = ["federation.vehicles_per_task=2", budgets]
    specs = client_specs(validate(compose_config(None, overrides)))
    assert [(s.task, s.agent.collision_budget) for s in specs] == [
        ("left", 0.14), ("straight", 0.08), ("right", 0.02),
        ("left", 0.14), ("straight", 0.08), ("right", 0.02),
    ]  # fmt: skip
    plain = client_specs(validate(compose_config(None, ["federation.vehicles_per_task=2"])))
    assert {s.agent.collision_budget for s in plain} == {0.02}
    assert all(s.agent.hidden_sizes == plain[0].agent.hidden_sizes for s in specs)
