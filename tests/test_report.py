"""frl.report on synthetic run directories: reading, aggregation, figures, markdown,
export, missing runs and bad input."""

import json
import math
import shutil
from types import SimpleNamespace

import numpy as np
import pytest
from report_helpers import evaluation, make_run

from frl.fileio import write_json_atomic
from frl.report import aggregate
from frl.report.__main__ import main as report_main
from frl.report.aggregate import CurveSettings, IntervalPoint
from frl.report.build import MissingDependency, build_report
from frl.report.collect import collect
from frl.report.markdown import fig6_block, runs_block
from frl.report.runs import RunDataError, export_run, load_run
from frl.report.stats import Estimate
from frl.reproduce import ExportRun, export_finished, export_if_stale
from frl.reproduce import main as reproduce_main

# One xdist worker runs this module: its tests share one results tree (a module fixture).
pytestmark = pytest.mark.xdist_group("report")

SETTINGS = CurveSettings(episode_window=2, step_window=3, threshold=6.0)
T2, T1 = 4.302653, 12.706205  # t(0.975, 2), t(0.975, 1)


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """fig4: central x 2 seeds, fedavg x 3, no separate; fig6: interval 5 x 2; fig3: the
    reference reward x 2 and one grid point; one unfinished fig6 run."""
    root = tmp_path_factory.mktemp("repro")
    central = {
        0: [(5, 2.0), (10, 6.0), (15, 8.0), (20, 8.0)],
        1: [(5, 6.0), (10, 6.0), (15, 6.0), (20, 6.0)],
    }
    for seed, rows in central.items():
        make_run(
            root / "fig4" / f"central-seed{seed}",
            "central",
            seed,
            episodes={"client0_random": rows},
            evaluation=evaluation(4.0, 0.03, 47.0),
        )
    for seed, last in ((0, 7.0), (1, 7.0), (2, 9.0)):
        episodes = {
            f"client{i}_{t}": [(10, 5.0), (20, last)]
            for i, t in enumerate(("left", "straight", "right"))
        }
        make_run(
            root / "fig4" / f"fedavg-seed{seed}",
            "fedavg",
            seed,
            episodes=episodes,
            evaluation=evaluation(6.0 + seed, 0.1, 40.0),
            total_bytes=1000,
        )
    for seed in (0, 1):
        make_run(
            root / "fig6" / f"interval5-seed{seed}",
            "fedavg",
            seed,
            interval=5,
            total_bytes=2000,
            evaluation=evaluation(5.0, 0.1, 40.0),
        )
        make_run(
            root / "fig3" / f"reference-seed{seed}",
            "central",
            seed,
            reward="reference",
            evaluation=evaluation(1.0, 0.02, 50.0),
        )
    make_run(
        root / "fig3" / "alpha-0.005_lambda-10-seed0",
        "central",
        0,
        reward="alpha-0.005_lambda-10",
        evaluation=evaluation(3.0, 0.0, 75.0),
    )
    unfinished = root / "fig6" / "interval250-seed0"
    unfinished.mkdir(parents=True)
    (unfinished / "state.json").write_text(json.dumps({"training_finished": False}))
    return root


def test_a_run_directory_reads_back_what_tensorboard_holds(root):
    run = load_run(root / "fig4" / "central-seed0")

    np.testing.assert_allclose(run.step_rewards, np.linspace(0, 1, 20), rtol=1e-6)
    episodes = run.episodes["client0_random"]
    assert episodes.end_step.tolist() == [5, 10, 15, 20]
    assert episodes.returns.tolist() == [2.0, 6.0, 8.0, 8.0]
    assert episodes.arrived.tolist() == [1, 1, 1, 1] and episodes.steps.tolist() == [10] * 4
    assert (run.scheme, run.seed, run.wall_time_s, run.git_commit[:4]) == (
        "central",
        0,
        60.0,
        "0123",
    )


def test_export_round_trips_and_reads_like_the_run(root, tmp_path):
    export_run(root / "fig4" / "fedavg-seed2", tmp_path / "fedavg-seed2")

    original = load_run(root / "fig4" / "fedavg-seed2")
    exported = load_run(tmp_path / "fedavg-seed2")
    assert sorted(p.name for p in (tmp_path / "fedavg-seed2").iterdir()) == [
        "config.yaml",
        "episodes.csv",
        "results.json",
        "step_rewards.csv",
    ]
    assert exported.results == original.results and exported.config == original.config
    np.testing.assert_allclose(exported.step_rewards, original.step_rewards, rtol=1e-6)
    assert exported.episodes.keys() == original.episodes.keys()
    for client, episodes in original.episodes.items():
        np.testing.assert_array_equal(exported.episodes[client].end_step, episodes.end_step)
        np.testing.assert_allclose(exported.episodes[client].returns, episodes.returns)


def test_fig4_threshold_steps_and_final_rewards_match_hand_computation(root):
    curves = aggregate.fig4(collect(root), SETTINGS)

    assert set(curves) == {"central", "fedavg"}  # separate: not run
    central = curves["central"]
    # window 2: seed 0's curve is 2 (steps 5-9), 4 (10-14), 7 (15-19), 8; seed 1's is 6 from 5
    assert central.crossings == [15, 5]
    assert central.crossing.mean == 10 and central.crossing.half_width == pytest.approx(
        T1 * math.sqrt(50) / math.sqrt(2), rel=1e-5
    )
    assert central.final_reward.mean == 7.0
    assert central.mean_curve_crossing == 15  # mean curve: 4 (steps 5-9), 5 (10-14), 6.5
    fedavg = curves["fedavg"]
    assert fedavg.crossings == [20, 20, 20]  # (5 + 7) / 2 = 6 at step 20
    finals = [6.0, 6.0, 7.0]
    assert fedavg.final_reward.mean == pytest.approx(np.mean(finals))
    assert fedavg.final_reward.half_width == pytest.approx(
        T2 * np.std(finals, ddof=1) / math.sqrt(3), rel=1e-5
    )
    assert np.isnan(fedavg.reward_mean[:9]).all() and fedavg.reward_mean[9] == 5.0


def test_a_lucky_episode_during_the_warm_up_is_not_a_crossing(tmp_path):
    # window 2: 6 (steps 5-9, one random-action episode), 4 (10-14), 5 (15-19), 8 (20)
    rows = [(5, 6.0), (10, 2.0), (15, 8.0), (20, 8.0)]
    for seed, learning_starts in ((0, 0), (1, 10)):
        make_run(
            tmp_path / "fig4" / f"central-seed{seed}",
            "central",
            seed,
            episodes={"client0_random": rows},
            learning_starts=learning_starts,
        )

    central = aggregate.fig4(collect(tmp_path), SETTINGS)["central"]

    assert central.crossings == [5, 20]
    assert central.mean_curve_crossing == 20  # the later warm-up of the two counts


def test_a_resumed_runs_wall_time_counts_every_session_and_the_test(tmp_path):
    run_dir = make_run(tmp_path / "fig4" / "fedavg-seed0", "fedavg", 0, wall_time_s=700.0)
    results = json.loads((run_dir / "results.json").read_text())
    # The training loop summed over two sessions; the job itself was only the second.
    results.update(job_wall_time_s=400.0, evaluation_wall_time_s=30.0)
    write_json_atomic(run_dir / "results.json", results)

    assert load_run(run_dir).wall_time_s == 730.0


def test_the_tested_curve_is_tabulated_per_round_over_the_seeds_each_run_has(tmp_path):
    # Seed 0 waits out round 1 (no arrival), then crosses; seed 1 has a third round that
    # seed 0 lacks, so only the two shared rounds are tabulated.
    curves = {
        0: [(10, 5.4, 0.0, 0.0), (20, 6.2, 0.05, 0.95)],
        1: [(10, 6.0, 0.1, 0.9), (20, 5.8, 0.05, 0.95), (30, 6.5, 0.0, 1.0)],
    }
    for seed, curve in curves.items():
        make_run(tmp_path / "fig4" / f"fedavg-seed{seed}", "fedavg", seed, round_tests=curve)
    make_run(tmp_path / "fig4" / "central-seed0", "central", 0)  # made without the curve

    tested = aggregate.tested_curves(collect(tmp_path), SETTINGS)
    written = build_report(tmp_path, tmp_path / "r.md", settings=SETTINGS)

    assert list(tested) == ["fedavg"]
    fed = tested["fedavg"]
    assert fed.steps == [10, 20] and fed.seeds == [0, 1] and fed.holds == [20, 30]
    returns = fed.metrics["average_reward"]
    assert returns[0].mean == pytest.approx(5.7) and returns[1].mean == pytest.approx(6.0)
    assert returns[0].half_width == pytest.approx(12.7062 * 0.3, rel=1e-4)  # t(0.975, 1)
    assert [e.mean for e in fed.metrics["arrival_rate"]] == pytest.approx([0.45, 0.95])
    text = (tmp_path / "r.md").read_text()
    assert written["fig4-tested"].exists()
    assert "The step from which the tested return holds 6: seed 0: 20, seed 1: 30." in text
    assert "| arrivals | 45.0 ± 571.8% | 95.0 ± 0.0% |" in text
    assert "**Central-DDPG**: not run yet." in text


def test_the_tested_curve_pairs_each_round_with_the_rule_on_the_same_episodes(tmp_path):
    # (step, return, collisions, arrivals); the rule's (return, collisions, arrivals) on
    # each seed's own round-test episodes.
    curves = {
        0: [(10, 5.0, 0.2, 0.8), (20, 5.6, 0.1, 0.9)],
        1: [(10, 6.2, 0.0, 1.0), (20, 6.0, 0.05, 0.95)],
    }
    rule = {0: (6.0, 0.05, 0.95), 1: (6.4, 0.0, 1.0)}
    for seed, curve in curves.items():
        make_run(tmp_path / "fig4" / f"fedavg-seed{seed}", "fedavg", seed, round_tests=curve,
                 round_test_yardsticks={"gap_acceptance": rule[seed],
                                        "oracle": (6.7, 0.0, 1.0)})  # fmt: skip

    fed = aggregate.tested_curves(collect(tmp_path), SETTINGS)["fedavg"]
    build_report(tmp_path, tmp_path / "r.md", settings=SETTINGS)

    gaps = fed.against_rule
    # Returns: seed 0 -1.0 then -0.4, seed 1 -0.2 then -0.4.
    assert [e.mean for e in gaps["average_reward"]] == pytest.approx([-0.6, -0.4])
    assert gaps["average_reward"][0].half_width == pytest.approx(12.7062 * 0.4, rel=1e-4)
    assert gaps["average_reward"][1].half_width == pytest.approx(0.0, abs=1e-12)
    assert [e.mean for e in gaps["collision_rate"]] == pytest.approx([0.075, 0.05])
    text = (tmp_path / "r.md").read_text()
    assert "| tested return - gap acceptance | -0.60 ± 5.08 | -0.40 ± 0.00 |" in text
    assert "| collisions - gap acceptance | 7.5 ± 95.3 pp | 5.0 ± 0.0 pp |" in text
    assert "the yardsticks on the round tests' own seeds" in text
    assert "gap acceptance 6.20 ± 2.54 / 2.5 ± 31.8% / 97.5 ± 31.8%" in text

    # One run without the rule on its curve's seeds: no pairing, and the lines fall back
    # to the final test's yardsticks.
    results = json.loads((tmp_path / "fig4" / "fedavg-seed1" / "results.json").read_text())
    del results["round_tests"]["yardsticks"]
    write_json_atomic(tmp_path / "fig4" / "fedavg-seed1" / "results.json", results)
    assert aggregate.tested_curves(collect(tmp_path), SETTINGS)["fedavg"].against_rule is None
    assert aggregate.tested_curve_yardsticks(collect(tmp_path)) == {}
    build_report(tmp_path, tmp_path / "r.md", settings=SETTINGS)
    assert "- gap acceptance |" not in (tmp_path / "r.md").read_text()


def test_fig6_borrows_the_fig4_interval_and_fig3_the_paper_reward(root):
    collection = collect(root)

    points = {p.interval: p for p in aggregate.fig6(collection, SETTINGS)}
    assert set(points) == {5, 10}
    assert points[10].borrowed and points[10].seeds == [0, 1, 2]
    assert not points[5].borrowed and points[5].total_bytes.mean == 2000
    assert points[10].test_reward.mean == 7.0
    rewards = {(p.name, p.alpha, p.lambda_): p for p in aggregate.fig3(collection)}
    assert rewards[("paper", -0.05, -10.0)].borrowed  # fig4's Central-DDPG runs
    assert rewards[("reference", -0.01, -1.0)].seeds == [0, 1]
    assert collection.unfinished["fig6"][0].name == "interval250-seed0"


def test_fig3_yardsticks_are_those_tested_with_the_paper_reward(tmp_path):
    # The oracle picks its start by the run's reward weights: under alpha -0.005 it waits
    # longer, so Fig. 3's yardstick rows must not take whichever reward comes first.
    for name, reward, oracle_steps in (
        ("fig3/alpha-0.005_lambda-10-seed0", "alpha-0.005_lambda-10", 48.0),
        ("fig4/central-seed0", "paper", 44.0),
    ):
        tested = evaluation(4.0, 0.1, 50.0)
        tested["yardsticks"] = {"oracle": evaluation(6.7, 0.0, oracle_steps)}
        make_run(tmp_path / name, "central", 0, reward=reward, evaluation=tested)

    yardsticks = aggregate.fig3_yardsticks(collect(tmp_path))

    assert yardsticks["oracle"].metrics["average"]["average_travel_time"].mean == 44.0


def test_fig6_sets_each_interval_beside_full_throttle_on_its_own_seeds(tmp_path):
    # Full throttle differs by seed (its traffic), so the gap is taken seed by seed.
    for seed, tested, blind in ((0, 5.0, 3.0), (1, 5.5, 4.0)):
        table = evaluation(tested, 0.1, 40.0)
        table["yardsticks"] = {
            "full_throttle": evaluation(blind, 0.2, 30.0),
            "oracle": evaluation(6.5, 0.0, 44.0),
        }
        run = tmp_path / "fig6" / f"interval500-seed{seed}"
        make_run(run, "fedavg", seed, interval=500, evaluation=table)
    make_run(tmp_path / "fig6" / "interval250-seed0", "fedavg", 0, interval=250)  # untested
    collection = collect(tmp_path)
    out = tmp_path / "results.md"

    points = {p.interval: p for p in aggregate.fig6(collection, SETTINGS)}
    written = build_report(tmp_path, out, settings=SETTINGS)

    gap = points[500].over_full_throttle
    assert (gap.mean, gap.half_width) == pytest.approx((1.75, T1 * 0.5 / 2))
    assert points[250].over_full_throttle is None
    yardsticks = aggregate.fig6_yardsticks(collection)
    assert yardsticks["full_throttle"].seeds == [0, 1]
    text = out.read_text()
    assert f"| 1.75 ± {T1 * 0.5 / 2:.2f} |" in text
    assert "full throttle 3.50 ± " in text and "oracle 6.50 ± 0.00" in text
    assert written["fig6"].exists()


def test_the_runs_table_lists_fig6_by_interval_not_by_name(tmp_path):
    for interval in (1000, 250, 500):
        make_run(tmp_path / "fig6" / f"interval{interval}-seed0", "fedavg", 0, interval=interval)

    text = runs_block(collect(tmp_path))

    rows = [line.split(" | ")[1] for line in text.splitlines() if line.startswith("| fig6 |")]
    assert rows == ["interval250-seed0", "interval500-seed0", "interval1000-seed0"]


def test_fig6_names_a_best_interval_over_the_seeds_every_interval_has():
    def point(interval: int, finals: dict[int, float], tests: dict[int, float]) -> IntervalPoint:
        seeds = sorted(finals)
        mean = Estimate(float(np.mean(list(finals.values()))), 0.5, len(seeds))
        return IntervalPoint(interval, seeds, False, mean, None, None, None, finals, tests)

    same = fig6_block(
        [
            point(500, {0: 4.0, 1: 4.0}, {0: 6.0, 1: 5.0}),
            point(2000, {0: 5.0, 1: 6.0}, {0: 5.0, 1: 4.0}),
        ],
        SETTINGS,
        None,
    )
    # interval 2,000 (fig4's runs) has a seed more: over seeds 0-1 alone 500 ends higher
    borrowed = fig6_block(
        [
            point(500, {0: 4.0, 1: 7.0}, {0: 5.0, 1: 5.0}),
            point(2000, {0: 5.0, 1: 5.0, 2: 9.0}, {0: 6.0, 1: 6.0, 2: 1.0}),
        ],
        SETTINGS,
        None,
    )
    disjoint = fig6_block([point(500, {0: 6.0}, {}), point(2000, {1: 5.0}, {})], SETTINGS, None)

    half = T1 * math.sqrt(0.5) / math.sqrt(2)
    assert (
        "Best interval over the seeds every interval has (0, 1): by final training reward "
        f"2,000 (5.50 ± {half:.2f}) and by test reward 500 (5.50 ± {half:.2f}); the paper: "
        "2,000 with 6.84" in same
    )
    assert (
        f"(0, 1): by final training reward 500 (5.50 ± {T1 * 1.5:.2f}) and by test reward "
        "2,000 (6.00 ± 0.00)" in borrowed
    )
    assert "Best interval" not in disjoint
    assert "No best interval is named: no seed has run at every interval." in disjoint


def test_report_writes_figures_and_tables_beside_the_paper(root, tmp_path):
    out = tmp_path / "docs" / "results.md"

    written = build_report(root, out, settings=SETTINGS)

    for name in ("fig3", "fig4", "fig5", "fig6"):
        assert written[name].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    text = out.read_text()
    assert "![Fig. 4](results/fig4.png)" in text
    half = T1 * math.sqrt(50) / math.sqrt(2)
    assert (
        f"| Central-DDPG | 2 (0, 1) | 10 ± {half:.0f} | 2/2: 15, 5 | 2/2: 15, 5 | 15 | 9,841 "
        "| 7.00 ± " in text
    )
    assert "| Sep-DDPG | not run yet |" in text
    assert f"| 6.33 ± {T2 * np.std([6, 6, 7], ddof=1) / math.sqrt(3):.2f} |" in text
    assert f"| FedAvg-DDPG | left | 3 | 7.00 ± {T2 / math.sqrt(3):.2f} | 10.0 ± 0.0% |" in text
    assert "| Sep-DDPG | left | not run yet |" in text
    assert "| 10 | 3 (0, 1, 2) (fig4) |" in text and "| 5 | 2 (0, 1) |" in text
    assert (
        "| 250 | not run yet |" in text and "| 2,000 | not run yet |  |  |  | 6.84 (best) |" in text
    )
    assert "| reference [22] | central | 2 (0, 1) | 50.00 ± 0.00 |" in text
    assert "| α=-0.05, λ=-10 | central | 2 (0, 1) (fig4) | 47.00 ± 0.00 |" in text
    assert "| α=-0.005, λ=-1 | not run yet |" in text
    assert "travel time (all) -6.00%, collision rate +1.0 pp (paper: -6.49%, +1 pp)" in text
    assert (
        "| fig4 | fedavg-seed2 | fedavg | 2 | 10 | α=-0.05, λ=-10 | 1.0 min | all | 0123456789 "
        "| yes |" in text
    )
    assert "Unfinished (not used): `fig6/interval250-seed0`" in text
    # interval 5 has seeds 0-1, interval 10 (fig4's runs) seeds 0-2: the best is named over
    # seeds 0-1 (interval 10's mean over 0-2 would compare traffic too)
    assert "Best interval over the seeds every interval has (0, 1): by final training" in text
    assert "Total wall time of the 10 finished runs: 10.0 min, the sum" in text


def test_rebuilding_keeps_hand_written_prose(root, tmp_path):
    out = tmp_path / "results.md"
    out.write_text(
        "# Results\n\nFedAvg converges first, as in the paper.\n\n"
        "<!-- frl.report:begin fig4 -->\n| stale |\n<!-- frl.report:end fig4 -->\n\n"
        "Hand-written discussion of Fig. 4.\n"
    )

    build_report(root, out, settings=SETTINGS)

    text = out.read_text()
    assert text.startswith("# Results\n\nFedAvg converges first, as in the paper.\n")
    assert "Hand-written discussion of Fig. 4." in text
    assert "| stale |" not in text and "| Sep-DDPG | not run yet |" in text
    assert text.count("<!-- frl.report:begin fig4 -->") == 1
    assert text.index("begin fig4") < text.index("Hand-written") < text.index("begin fig6")


def test_a_report_from_fig4_alone_marks_the_other_figures_not_run(root, tmp_path):
    only = tmp_path / "only"
    export_run(root / "fig4" / "fedavg-seed0", only / "fig4" / "fedavg-seed0")

    written = build_report(only, tmp_path / "r.md", settings=SETTINGS)

    text = (tmp_path / "r.md").read_text()
    assert "fig3" not in written and "fig6" in written  # fig6: the borrowed interval
    assert "Best interval here" not in (tmp_path / "r.md").read_text()  # one point: no best
    assert "## Fig. 3: reward tuning\n\n<!-- frl.report:begin fig3 -->\n_not run yet_" in text
    assert "(n=1)" in text


def test_bad_input_fails_before_any_work(tmp_path, capsys, monkeypatch):
    with pytest.raises(RunDataError, match="no such directory"):
        collect(tmp_path / "missing")
    with pytest.raises(RunDataError, match="no runs found"):
        collect(tmp_path)
    (tmp_path / "fig4" / "fedavg-seed0").mkdir(parents=True)
    (tmp_path / "fig4" / "fedavg-seed0" / "state.json").write_text('{"training_finished": false}')
    with pytest.raises(RunDataError, match="no finished run yet"):
        collect(tmp_path)

    assert report_main([str(tmp_path / "missing"), "--out", str(tmp_path / "r.md")]) == 2
    assert "no such directory" in capsys.readouterr().err
    assert not (tmp_path / "r.md").exists()
    with pytest.raises(SystemExit):
        reproduce_main(["--figures", "fig4,fig7", "--dry-run"])
    assert "unknown figure fig7" in capsys.readouterr().err

    monkeypatch.setattr("importlib.util.find_spec", lambda name: None)
    with pytest.raises(MissingDependency, match=r"pip install .*\[report\]"):
        build_report(tmp_path, tmp_path / "r.md")


def test_export_callback_and_export_only_skip_what_is_current(root, tmp_path):
    run_dir = root / "fig4" / "central-seed1"
    callback = ExportRun(str(tmp_path / "data" / "fig4"))
    from hydra.core.utils import JobStatus

    job = SimpleNamespace(status=JobStatus.COMPLETED)
    callback.on_job_end({"run_dir": str(run_dir)}, job)

    exported = tmp_path / "data" / "fig4" / "central-seed1"
    assert load_run(exported).results == load_run(run_dir).results
    written = export_finished(root, tmp_path / "data")
    assert exported not in written and len(written) == 9  # everything else; not unfinished
    assert export_finished(root, tmp_path / "data") == []


def test_export_only_exports_the_agent_panels_in_their_layout(root, tmp_path):
    runs = tmp_path / "runs"
    shutil.copytree(root / "fig4" / "fedavg-seed0", runs / "guided" / "fig4" / "fedavg-seed0")

    written = export_finished(runs, tmp_path / "data")

    assert written == [tmp_path / "data" / "guided" / "fig4" / "fedavg-seed0"]
    assert load_run(written[0]).results == load_run(root / "fig4" / "fedavg-seed0").results


def test_a_failed_job_is_logged_when_it_ends_not_when_the_sweep_does(root, tmp_path, caplog):
    from hydra.core.utils import JobStatus

    try:
        raise RuntimeError("the test could not start")
    except RuntimeError as error:
        failed = SimpleNamespace(status=JobStatus.FAILED, _return_value=error)
    run_dir = root / "fig4" / "central-seed1"

    ExportRun(str(tmp_path / "data")).on_job_end({"run_dir": str(run_dir)}, failed)

    assert f"{run_dir} failed: Traceback" in caplog.text
    assert "RuntimeError: the test could not start" in caplog.text
    assert not (tmp_path / "data").exists()


def test_export_records_the_versions_the_run_trained_with(root, tmp_path):
    run_dir = root / "fig4" / "fedavg-seed2"
    write_json_atomic(run_dir / "versions.json", {"git_commit": "feedbeef", "git_dirty": False})

    export_run(run_dir, tmp_path / "fedavg-seed2")

    exported = load_run(tmp_path / "fedavg-seed2")
    assert exported.git_commit == "feedbeef"  # not results.json's commit at the run's end
    assert not export_if_stale(run_dir, tmp_path / "fedavg-seed2")  # current: not redone


def test_reward_gain_is_relative_only_over_a_positive_baseline():
    from frl.report.markdown import _reward_gain

    assert _reward_gain(6.0, 5.0) == "+20.00%"
    assert _reward_gain(-2.46, -0.77) == "-1.69 (difference: baseline <= 0)"
    assert _reward_gain(float("nan"), 1.0) == "–"
