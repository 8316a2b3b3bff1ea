"""The claims table: paired differences over seeds, their verdicts, and the report's
claims, yardstick and Table II blocks, on synthetic runs with hand-computed numbers."""

import math
import shutil

import pytest
from report_helpers import TASKS, evaluation, make_run

from frl.report.aggregate import CurveSettings
from frl.report.build import build_report
from frl.report.claims import (
    Claim,
    fig3_claims,
    fig4_fig5_claims,
    fig6_claims,
    hold_claims,
    per_round_test_curve,
    training_curve,
    verdict,
)
from frl.report.markdown import claims_block
from frl.report.measures import paired
from frl.report.runs import load_run
from frl.report.stats import Estimate

# One xdist worker runs this module: its tests share one results tree (a module fixture).
pytestmark = pytest.mark.xdist_group("report-claims")

SETTINGS = CurveSettings(episode_window=2, step_window=3, threshold=6.0)
T2 = 4.302653  # t(0.975, 2)


@pytest.mark.parametrize(
    ("estimate", "sign", "expected"),
    [
        (Estimate(2.0, 1.0, 3), +1, "holds (significant)"),
        (Estimate(-2.0, 1.0, 3), +1, "opposite (significant)"),
        (Estimate(-2.0, 1.0, 3), -1, "holds (significant)"),
        (Estimate(0.5, 1.0, 3), +1, "same direction, not significant"),
        (Estimate(-0.5, 1.0, 3), +1, "opposite direction, not significant"),
        (Estimate(0.5, None, 1), +1, "one seed: no interval"),
        (None, +1, "not run"),
    ],
)
def test_a_verdict_needs_an_interval_that_excludes_zero(estimate, sign, expected):
    assert verdict(estimate, sign) == expected


def test_the_claims_table_puts_each_unit_before_a_lone_seeds_marker():
    rows = [Claim("3", "c", "p", f"m{i}", estimate, +1, unit) for i, (estimate, unit) in
            enumerate([(Estimate(29.94, None, 1), " steps"), (Estimate(-0.05, 0.01, 3), "pp"),
                       (Estimate(0.5, None, 1), "%"), (None, " steps")])]  # fmt: skip
    text = claims_block(rows)
    assert "| m0 | 29.9 steps (n=1) |" in text and "| m1 | -5.0 ± 1.0 pp |" in text
    assert "| m2 | 50.0% (n=1) |" in text and "| m3 | – |" in text


def test_a_step_count_prints_as_whole_steps_with_thousands_separated():
    rows = [
        Claim("4", "c", "p", "held", Estimate(10000.0, None, 1), +1, " steps", digits=0),
        Claim("4", "c", "p", "reached", Estimate(4593.4, 812.6, 3), +1, " steps", digits=0),
    ]
    text = claims_block(rows)
    assert "| held | 10,000 steps (n=1) |" in text
    assert "| reached | 4,593 ± 813 steps |" in text


def test_differences_are_paired_over_the_seeds_both_hold():
    difference = paired({0: 1.0, 1: 3.0, 2: 5.0}, {0: 0.0, 1: 1.0, 2: 2.0, 3: 9.0})
    assert difference is not None
    assert difference.n == 3 and difference.mean == pytest.approx(2.0)
    assert difference.half_width == pytest.approx(T2 * 1.0 / math.sqrt(3), rel=1e-5)
    assert paired({0: 1.0}, {1: 1.0}) is None


def test_fig6_takes_the_best_other_interval_seed_by_seed(tmp_path):
    # Interval 250 has the higher mean over its own seeds (5 against 4), but seed for seed
    # interval 2,500 comes closer to 2,000: its one seed beats 2,000 there by 2.
    finals = {2000: {0: 8.0, 1: 2.0, 2: 5.0}, 250: {0: 9.0, 1: 1.0}, 2500: {1: 4.0}}
    runs: dict[int, list] = {}
    for interval, by_seed in finals.items():
        for seed, final in by_seed.items():
            episodes = {f"client{i}_{t}": [(10, final), (20, final)] for i, t in enumerate(TASKS)}
            path = make_run(tmp_path / f"interval{interval}-seed{seed}", "fedavg", seed,
                            interval=interval, episodes=episodes)  # fmt: skip
            runs.setdefault(interval, []).append(load_run(path))

    claim, short, long = fig6_claims(runs, SETTINGS)

    assert claim.note == "best other interval: 2,500, over seeds 1"
    assert claim.ours.mean == pytest.approx(-2.0) and claim.verdict == "one seed: no interval"
    # Biphasic: 2,000 against the shortest (250) and the longest (2,500) interval.
    assert short.measure == "final training reward, interval 2,000 - interval 250"
    assert short.ours.mean == pytest.approx(0.0) and short.ours.n == 2
    assert long.measure.endswith("interval 2,500") and long.ours.mean == pytest.approx(-2.0)
    del runs[2500]
    claim, short, long = fig6_claims(runs, SETTINGS)
    assert claim.note == "best other interval: 250, over seeds 0, 1"
    assert claim.ours.mean == pytest.approx(0.0) and claim.ours.n == 2
    assert short.ours == long.ours  # one other interval: the shortest is the longest
    del runs[250]
    _, short, long = fig6_claims(runs, SETTINGS)
    assert short.measure.endswith("the shortest interval") and short.verdict == "not run"


def test_fig6_is_tested_on_the_test_reward_as_well_as_on_the_training_reward(tmp_path):
    # The training curves end level (5 at every interval); the test rewards peak at 2,000.
    tests = {
        250: {0: 4.0, 1: 5.0},
        2000: {0: 6.0, 1: 6.5},
        1000: {0: 5.5, 1: 6.5},
        10000: {0: 2.0, 1: 2.5},
    }
    runs: dict[int, list] = {}
    for interval, by_seed in tests.items():
        for seed, test in by_seed.items():
            episodes = {f"client{i}_{t}": [(10, 5.0), (20, 5.0)] for i, t in enumerate(TASKS)}
            path = make_run(tmp_path / f"interval{interval}-seed{seed}", "fedavg", seed,
                            interval=interval, episodes=episodes,
                            evaluation=evaluation(test, 0.1, 50))  # fmt: skip
            runs.setdefault(interval, []).append(load_run(path))

    trained = fig6_claims(runs, SETTINGS)
    best, short, long = fig6_claims(runs, SETTINGS, tested=True)

    assert all(claim.ours.mean == pytest.approx(0.0) for claim in trained)
    assert best.measure == "test reward, interval 2,000 - the best other interval"
    assert best.paper == "6.84 at 2,000 (training reward)"
    assert best.note == "best other interval: 1,000, over seeds 0, 1"
    assert best.ours.mean == pytest.approx(0.25) and best.ours.n == 2
    assert short.measure == "test reward, interval 2,000 - interval 250"
    assert short.ours.mean == pytest.approx(1.75) and long.ours.mean == pytest.approx(4.0)
    assert short.verdict == "same direction, not significant"
    assert long.verdict == "holds (significant)"


def test_fig3_tests_the_weightings_the_paper_discusses_against_its_choice(tmp_path):
    # Per seed: the balanced weighting takes 50 steps with 10% collisions; the light time
    # cost 70-74 steps with none; the light collision penalty 45 steps with 20%.
    def runs(name: str, steps: list[float], collisions: float) -> list:
        return [load_run(make_run(tmp_path / f"{name}-seed{seed}", "central", seed,
                                  evaluation=evaluation(5.0, collisions, s)))
                for seed, s in enumerate(steps)]  # fmt: skip

    balanced = runs("balanced", [50, 50, 50], 0.1)
    slow, reckless = runs("slow", [70, 72, 74], 0.0), runs("reckless", [45, 45, 45], 0.2)

    claims = {c.claim: c for c in fig3_claims(balanced, [], slow, reckless)}

    slower = claims["a light time cost (α=-0.005, λ=-10) prolongs the travel time"]
    assert slower.ours.mean == pytest.approx(22.0) and slower.verdict == "holds (significant)"
    assert claims["... and collides less: none"].ours.mean == pytest.approx(-0.1)
    riskier = claims["a light collision penalty (α=-0.05, λ=-1) raises collisions"]
    assert riskier.ours.mean == pytest.approx(0.1) and riskier.paper == "9%"
    assert claims["... and shortens the travel time (fewer arrive)"].ours.mean == -5.0
    assert claims["α=-0.05, λ=-10 drives faster than the reference reward"].verdict == "not run"


def _with_yardstick(table: dict, reward: float, collisions: float) -> dict:
    blind = evaluation(reward, collisions, 30.0)
    return {**table, "yardsticks": {"full_throttle": blind, "oracle": evaluation(6.5, 0, 44)}}


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """fig4: FedAvg tests 3, 3.5 and 4 above Sep-DDPG at seeds 0-2 and collides 5 pp less
    at each; Central-DDPG at seed 0 only. Full throttle scores 3.0 and collides 20%."""
    root = tmp_path_factory.mktemp("claims")
    for seed in (0, 1, 2):
        sep = _with_yardstick(evaluation(4.0, 0.15, 40.0), 3.0, 0.2)
        fed = _with_yardstick(evaluation(7.0 + seed / 2, 0.1, 40.0), 3.0, 0.2)
        make_run(root / "fig4" / f"separate-seed{seed}", "separate", seed, evaluation=sep)
        make_run(root / "fig4" / f"fedavg-seed{seed}", "fedavg", seed, evaluation=fed)
    make_run(root / "fig4" / "central-seed0", "central", 0, evaluation=evaluation(1.0, 0.3, 40.0))
    return root


def test_each_claim_gets_our_paired_estimate_and_verdict(root):
    runs = [load_run(p) for p in sorted((root / "fig4").iterdir())]
    claims = {c.measure: c for c in fig4_fig5_claims(runs, SETTINGS)}

    better = claims["test reward, FedAvg-DDPG - Sep-DDPG"]
    assert better.ours.mean == pytest.approx(3.5)
    assert better.ours.half_width == pytest.approx(T2 * 0.5 / math.sqrt(3), rel=1e-5)
    assert better.verdict == "holds (significant)"
    fewer = claims["collision rate, FedAvg-DDPG - Sep-DDPG"]
    assert fewer.ours.mean == pytest.approx(-0.05) and fewer.ours.half_width == pytest.approx(0)
    assert fewer.verdict == "holds (significant)"
    assert claims["test reward, Central-DDPG - Sep-DDPG"].verdict == "one seed: no interval"
    blind = claims["test reward, FedAvg-DDPG - full throttle, same seeds"]
    assert blind.ours.mean == pytest.approx(4.5) and blind.verdict == "holds (significant)"
    # Training returns of the helper's runs end at 7 for every scheme: no difference.
    same = claims["final training reward, FedAvg-DDPG - Sep-DDPG"]
    assert same.ours.mean == 0 and same.verdict == "opposite direction, not significant"
    reached = claims["first step at or above 6, over the seeds that reach it"]
    assert reached.verdict == "reached at 3 of 3 seeds" and reached.ours.mean == 20


def test_the_report_tabulates_claims_draws_yardsticks_and_the_table_ii_agent(root, tmp_path):
    table_ii = root / "paper-agent" / "fig4" / "fedavg-seed0"
    make_run(table_ii, "fedavg", 0, evaluation=_with_yardstick(evaluation(2.5, 0.3, 40), 3.0, 0.2))
    out = tmp_path / "results.md"

    written = build_report(root, out, settings=SETTINGS)

    text = out.read_text()
    assert (
        f"| 5 | FedAvg-DDPG tests better than Sep-DDPG | bars only | test reward, FedAvg-DDPG - "
        f"Sep-DDPG | 3.50 ± {T2 * 0.5 / math.sqrt(3):.2f} | holds (significant) |" in text
    )
    assert "| -5.0 ± 0.0 pp | holds (significant) |" in text
    assert "| 3 | α=-0.05, λ=-10 drives faster than the reference reward | -6.49% |" in text
    assert "Reference lines: the yardsticks' test return" in text
    assert "full throttle 3.00 ± 0.00, oracle 6.50 ± 0.00" in text
    for name in ("fig4-paper-agent", "fig5-paper-agent"):
        assert written[name].exists() and f"<!-- frl.report:begin {name} -->" in text
    assert "<!-- frl.report:begin claims-paper-agent -->" in text
    assert "| FedAvg-DDPG | left | 1 | 2.50 (n=1) |" in text


def _block(text: str, name: str) -> str:
    return text[text.index(f"begin {name} -->") : text.index(f"end {name} -->")]


def test_the_guided_agent_is_a_panel_of_its_own_never_mixed_in(root, tmp_path):
    mine = tmp_path / "root"
    shutil.copytree(root, mine)
    build_report(mine, tmp_path / "without" / "results.md", settings=SETTINGS)
    curves = {"fedavg": [(10, 5.0), (20, 6.5)], "separate": [(10, 7.0), (20, 5.0), (30, 6.0)]}
    for seed in (0, 1):  # FedAvg's tested return holds 6 from step 20, Sep-DDPG's from 30
        for scheme, curve in curves.items():
            run_dir = mine / "guided" / "fig4" / f"{scheme}-seed{seed}"
            tested = evaluation(6.5, 0.05, 40)
            make_run(run_dir, scheme, seed, total_steps=30, evaluation=tested, round_tests=curve)

    written = build_report(mine, tmp_path / "with" / "results.md", settings=SETTINGS)

    without, text = ((tmp_path / edition / "results.md").read_text()
                     for edition in ("without", "with"))  # fmt: skip
    for name in ("claims", "fig4", "fig5", "runs"):  # the default agent's blocks: untouched
        assert _block(text, name) == _block(without, name)
    for name in ("fig4-guided", "fig5-guided"):
        assert written[name].exists() and f"<!-- frl.report:begin {name} -->" in text
    # Without its runs the template's guided section says how to make them.
    hint = "needs `guided/fig4/` runs: `python -m frl.reproduce --figures fig4-guided`"
    assert hint in _block(without, "claims-guided") and hint in _block(without, "runs-guided")
    assert hint not in text
    guided = _block(text, "claims-guided")
    assert "| 4 | FedAvg-DDPG's tested return holds 6 | step 4,593 (training reward) |" in guided
    assert "| 20 ± 0 steps | held at 2 of 2 seeds |" in guided
    assert "| 50.0 ± 0.0% |" in guided  # Sep-DDPG: 30 steps against 20, at both seeds
    assert "fedavg-seed1" in _block(text, "runs-guided")
    assert "guided" not in _block(text, "runs")


def test_gap_acceptance_rows_appear_only_for_runs_tested_beside_it(root, tmp_path):
    runs = [load_run(p) for p in sorted((root / "fig4").iterdir())]
    measures = {c.measure for c in fig4_fig5_claims(runs, SETTINGS)}
    assert not any("gap acceptance" in measure for measure in measures)
    for seed in (0, 1):  # FedAvg at 7.0 and 7.5, 10% collisions; the rule 6.6 and 4%
        table = _with_yardstick(evaluation(7.0 + seed / 2, 0.1, 40.0), 3.0, 0.2)
        table["yardsticks"]["gap_acceptance"] = evaluation(6.6, 0.04, 60.0)
        make_run(tmp_path / f"fedavg-seed{seed}", "fedavg", seed, evaluation=table)
    runs = [load_run(tmp_path / f"fedavg-seed{seed}") for seed in (0, 1)]
    claims = {c.measure: c for c in fig4_fig5_claims(runs, SETTINGS)}
    better = claims["test reward, FedAvg-DDPG - gap acceptance, same seeds"]
    assert better.ours.mean == pytest.approx(0.65)
    assert better.verdict == "same direction, not significant"
    safer = claims["collision rate, FedAvg-DDPG - gap acceptance, same seeds"]
    assert safer.ours.mean == pytest.approx(0.06) and safer.expected_sign == -1
    assert safer.verdict == "opposite (significant)"  # +6 pp at both seeds
    arrives = claims["arrival rate, FedAvg-DDPG - gap acceptance, same seeds"]
    assert arrives.ours.mean == pytest.approx(-0.06)


def _tested_runs(tmp_path, curves: dict[tuple[str, int], list[float]]) -> list:
    """Runs whose per-round tests (every 2 steps) return ``curves[scheme, seed]``."""
    runs = []
    for (scheme, seed), returns in curves.items():
        points = [(2 * (i + 1), r) for i, r in enumerate(returns)]
        path = make_run(tmp_path / f"{scheme}-seed{seed}", scheme, seed, round_tests=points)
        runs.append(load_run(path))
    return runs


def test_the_claims_on_tested_curve_take_the_step_each_scheme_holds_the_threshold(tmp_path):
    runs = _tested_runs(tmp_path, {
        ("fedavg", 0): [5.0, 6.1, 6.3, 6.2],  # holds from step 4
        ("fedavg", 1): [6.5, 5.9, 6.1, 6.0],  # dips at 4: holds from step 6
        ("fedavg", 2): [5.0, 6.2, 6.4, 6.9],  # holds from step 4
        ("separate", 0): [5.0, 5.5, 6.0, 6.1],  # holds from 6: 6 / 4 - 1 = +50%
        ("separate", 1): [5.0, 5.5, 6.2, 6.3],  # holds from 6: 6 / 6 - 1 = 0
        ("separate", 2): [6.2, 6.3, 6.4, 5.8],  # ends below: never holds
    })  # fmt: skip
    runs.append(load_run(make_run(tmp_path / "central-seed0", "central", 0)))  # no curve

    holds, sooner_than_sep, sooner_than_central = hold_claims(
        runs, SETTINGS, per_round_test_curve, "tested return"
    )

    assert holds.ours.mean == pytest.approx(14 / 3) and holds.ours.n == 3
    assert holds.verdict == "held at 3 of 3 seeds"
    assert sooner_than_sep.ours.mean == pytest.approx(0.25) and sooner_than_sep.ours.n == 2
    assert sooner_than_sep.verdict == "same direction, not significant"
    assert sooner_than_central.ours is None and sooner_than_central.verdict == "not run"
    row = claims_block([sooner_than_sep])
    assert f"| 25.0 ± {12.706205 * 25:.1f}% |" in row  # ratios 0.5, 0: t(0.975, 1) s / sqrt(2)


def test_a_scheme_that_never_holds_the_threshold_is_named_with_its_seeds(tmp_path):
    runs = _tested_runs(tmp_path, {
        ("fedavg", 0): [5.0, 5.5], ("fedavg", 1): [6.1, 6.2],
        ("separate", 0): [6.5, 5.5], ("separate", 1): [5.0, 5.9],
    })  # fmt: skip

    holds, sooner_than_sep, _ = hold_claims(runs, SETTINGS, per_round_test_curve, "tested return")

    assert holds.verdict == "held at 1 of 2 seeds (not at seed 0)"
    assert sooner_than_sep.ours is None
    assert sooner_than_sep.verdict == (
        "no seed where both hold: FedAvg-DDPG held at 1 of 2 seeds (not at seed 0), "
        "Sep-DDPG held at 0 of 2 seeds"
    )


def test_the_training_curve_claims_pair_the_steps_each_scheme_holds_the_threshold(tmp_path):
    # Window 2: FedAvg's training reward is 7 from its first episode end (step 10) on,
    # Sep-DDPG's 5 at step 10, then (5 + 7) / 2 = 6 from step 20 on.
    fed = {f"client{i}_{t}": [(10, 7.0), (20, 7.0)] for i, t in enumerate(TASKS)}
    runs = [
        load_run(make_run(tmp_path / "fedavg-seed0", "fedavg", 0, episodes=fed)),
        load_run(make_run(tmp_path / "separate-seed0", "separate", 0)),
    ]

    holds, sooner_than_sep, _ = hold_claims(
        runs, SETTINGS, training_curve(SETTINGS), "training reward"
    )

    assert holds.ours.mean == 10 and holds.verdict == "held at 1 of 1 seeds"
    assert sooner_than_sep.ours.mean == pytest.approx(20 / 10 - 1)
    assert sooner_than_sep.verdict == "one seed: no interval"
    assert sooner_than_sep.measure == (
        "Sep-DDPG's step / FedAvg-DDPG's - 1 (training reward), seeds where both hold"
    )
