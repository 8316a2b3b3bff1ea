"""The paper's claims, one row each: our estimate, the paper's number, and a verdict.

Every comparison is paired over seeds: the schemes of one seed train and test on the
same seeds' traffic, so the difference per seed is the measurement, and its mean gets a
95% t interval over seeds (frl.report.stats). A difference is *significant* when that
interval excludes zero. With three seeds the t quantile is 4.30, so only large, steady
differences are.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from frl.report.aggregate import (
    PAPER_INTERVAL,
    PAPER_REWARD_KEY,
    RULE,
    SCHEME_LABELS,
    CurveSettings,
    fig3_runs,
    fig6_runs,
    final_training_reward,
    group,
    reward_curve,
)
from frl.report.collect import Collection
from frl.report.measures import (
    Metric,
    PerSeed,
    paired,
    per_seed,
    test_metric,
    yardstick_metric,
)
from frl.report.runs import RunRecord
from frl.report.stats import Estimate, first_crossing, first_hold, mean_ci


@dataclass(frozen=True)
class Claim:
    figure: str
    claim: str
    """The paper's claim."""
    paper: str
    """The paper's number for it, if it gives one."""
    measure: str
    """What we compare, as ``A - B`` per seed."""
    ours: Estimate | None
    """Mean difference and its interval; None: not run."""
    expected_sign: int
    """+1 if the claim says ``A - B > 0``, -1 if ``< 0``."""
    unit: str = ""
    """``pp``: a difference of rates, shown in percentage points; ``%``: a ratio less one,
    shown in percent."""
    note: str = ""
    settled: str | None = None
    """A verdict that is no comparison (a threshold reached at k of n seeds)."""
    digits: int | None = None
    """Decimals shown; None: one for rates, ratios and steps, two otherwise."""

    @property
    def verdict(self) -> str:
        return self.settled or verdict(self.ours, self.expected_sign)


def verdict(difference: Estimate | None, expected_sign: int) -> str:
    """``holds``, ``opposite``, ``not significant`` or why there is no verdict."""
    if difference is None or not math.isfinite(difference.mean):
        return "not run"
    if difference.half_width is None:
        return "one seed: no interval"
    same = difference.mean * expected_sign > 0
    assert difference.low is not None and difference.high is not None
    significant = difference.low > 0 or difference.high < 0
    if significant:
        return "holds (significant)" if same else "opposite (significant)"
    return "same direction, not significant" if same else "opposite direction, not significant"


def mean_training_reward(settings: CurveSettings) -> Metric:
    """The Fig. 4 curve averaged over the steps after the warm-up: higher is faster."""

    def read(run: RunRecord) -> float | None:
        curve = reward_curve(run, settings.episode_window)[run.learning_starts :]
        return float(np.nanmean(curve)) if np.isfinite(curve).any() else None

    return read


def crossing_step(settings: CurveSettings) -> Metric:
    def read(run: RunRecord) -> float | None:
        curve = reward_curve(run, settings.episode_window)
        step = first_crossing(curve, settings.threshold, after=run.learning_starts)
        return None if step is None else float(step)

    return read


SLOW_RECKLESS = ((-0.005, -10.0), (-0.05, -1.0))
"""Fig. 3's (alpha, lambda) that the paper discusses beside its choice: a light time cost
(collision-free but slow) and a light collision penalty (9% collisions)."""
PAPER_SPEED_UPS = (("separate", "32.11"), ("central", "114.26"))
"""Fig. 4: how many more steps (%) each baseline needs than FedAvg-DDPG to reach 6."""

Curve = Callable[[RunRecord], "tuple[Sequence[int], Sequence[float]] | None"]
"""A run's curve as (steps, values), or None where the run has none."""


def training_curve(settings: CurveSettings) -> Curve:
    """Fig. 4's training curve (``rollout/ep_rew_mean``) at every step."""

    def read(run: RunRecord) -> tuple[Sequence[int], Sequence[float]]:
        curve = reward_curve(run, settings.episode_window)
        return range(1, curve.size + 1), curve

    return read


def per_round_test_curve(run: RunRecord) -> tuple[Sequence[int], Sequence[float]] | None:
    """The per-round test curve (``round_test_episodes``), without exploration noise."""
    return run.round_test_curve


def hold_claims(
    runs: list[RunRecord], settings: CurveSettings, curve: Curve, name: str
) -> list[Claim]:
    """Fig. 4's convergence claims as the paper states them: the step from which each
    scheme's ``curve`` (called ``name`` in the table) holds the threshold, per seed, and
    the other schemes' step over FedAvg-DDPG's, paired over the seeds where both hold."""
    tested: dict[str, list[int]] = {}
    """Per scheme, the seeds whose runs have the curve."""
    steps: dict[str, PerSeed] = {}
    """Per scheme and seed, the step from which the curve holds the threshold."""
    for run in runs:
        points = curve(run)  # computed once a run: the training curve is not cheap
        if points is None:
            continue
        tested.setdefault(run.scheme, []).append(run.seed)
        step = first_hold(*points, settings.threshold)
        if step is not None:
            steps.setdefault(run.scheme, {})[run.seed] = float(step)
    fed, threshold = SCHEME_LABELS["fedavg"], f"{settings.threshold:g}"

    def held(scheme: str) -> str:
        seeds = sorted(tested.get(scheme, []))
        if not seeds:
            return "not run"
        missed = [seed for seed in seeds if seed not in steps.get(scheme, {})]
        where = f" (not at seed{'s' * (len(missed) > 1)} {', '.join(map(str, missed))})"
        some = 0 < len(missed) < len(seeds)  # which seeds missed, where not all did
        return f"held at {len(seeds) - len(missed)} of {len(seeds)} seeds" + (where if some else "")

    fed_steps = steps.get("fedavg", {})
    claims = [
        Claim("4", f"{fed}'s {name} holds {threshold}", "step 4,593 (training reward)",
              f"first step from which the {name} stays at or above {threshold}, "
              "over the seeds that hold it",
              mean_ci(list(fed_steps.values())) if fed_steps else None, +1, unit=" steps",
              settled=held("fedavg"), digits=0),
    ]  # fmt: skip
    for other, speed in PAPER_SPEED_UPS:
        label = SCHEME_LABELS[other]
        other_steps = steps.get(other, {})
        ratios = {s: other_steps[s] / fed_steps[s] - 1 for s in set(fed_steps) & set(other_steps)}
        settled = None
        if not (tested.get("fedavg") and tested.get(other)):
            settled = "not run"
        elif not ratios:
            settled = f"no seed where both hold: {fed} {held('fedavg')}, {label} {held(other)}"
        claims.append(
            Claim("4", f"{fed}'s {name} holds {threshold} sooner than {label}'s",
                  f"{label} needs {speed}% more steps",
                  f"{label}'s step / {fed}'s - 1 ({name}), seeds where both hold",
                  mean_ci(list(ratios.values())) if ratios else None, +1, unit="%",
                  settled=settled)
        )  # fmt: skip
    return claims


# ------------------------------------------------------------------- claims
def fig4_fig5_claims(runs: list[RunRecord], settings: CurveSettings) -> list[Claim]:
    """Figs. 4 and 5: FedAvg-DDPG against each baseline, and against full throttle."""
    by_scheme = group(runs, lambda run: run.scheme)

    def of(scheme: str, metric: Metric) -> PerSeed:
        return per_seed(by_scheme.get(scheme, []), metric)

    def diff(metric: Metric, a: str, b: str) -> Estimate | None:
        return paired(of(a, metric), of(b, metric))

    fed = SCHEME_LABELS["fedavg"]
    claims = []
    crossing = crossing_step(settings)
    crossed = per_seed(by_scheme.get("fedavg", []), crossing)
    seeds = len(by_scheme.get("fedavg", []))
    claims.append(
        Claim(
            "4",
            f"{fed} reaches the benchmark training reward {settings.threshold:g}",
            "step 4,593",
            f"first step at or above {settings.threshold:g}, over the seeds that reach it",
            mean_ci(list(crossed.values())) if crossed else None,
            +1,
            unit=" steps",
            settled=(f"reached at {len(crossed)} of {seeds} seeds" if seeds else "not run"),
            digits=0,
        )
    )
    for other, speed in PAPER_SPEED_UPS:
        label = SCHEME_LABELS[other]
        claims += [
            Claim("4", f"{fed} converges faster than {label}",
                  f"{label} needs {speed}% more steps to reach {settings.threshold:g}",
                  f"mean training reward after the warm-up, {fed} - {label}",
                  diff(mean_training_reward(settings), "fedavg", other), +1),
            Claim("4", f"{fed} ends with a higher training reward than {label}", "+21.00%",
                  f"final training reward, {fed} - {label}",
                  diff(final_training_reward(settings), "fedavg", other), +1),
        ]  # fmt: skip
    test_reward, collisions = test_metric("average_reward"), test_metric("collision_rate")
    sep, central = SCHEME_LABELS["separate"], SCHEME_LABELS["central"]
    claims += [
        Claim("5", f"{fed} tests better than {sep}", "bars only", f"test reward, {fed} - {sep}",
              diff(test_reward, "fedavg", "separate"), +1),
        Claim("5", f"{fed} markedly lowers collisions against {sep}", "bars only",
              f"collision rate, {fed} - {sep}", diff(collisions, "fedavg", "separate"), -1, "pp"),
    ]  # fmt: skip
    for task in ("left", "straight", "right"):
        claims.append(
            Claim("5", f"... on every task: {task}", "bars only",
                  f"collision rate ({task}), {fed} - {sep}",
                  diff(test_metric("collision_rate", task), "fedavg", "separate"), -1, "pp")
        )  # fmt: skip
    # The paper's travel time counts every episode to its end, collisions included.
    travel = test_metric("average_episode_steps")
    claims.append(
        Claim("5", f"... and travels faster than {sep}", "bars only",
              f"travel time (all episodes, steps), {fed} - {sep}",
              diff(travel, "fedavg", "separate"), -1, " steps")
    )  # fmt: skip
    for other in ("separate", "fedavg"):
        label = SCHEME_LABELS[other]
        claims += [
            Claim("5", f"{central} tests worst: below {label}", "bars only",
                  f"test reward, {central} - {label}", diff(test_reward, "central", other), -1),
            Claim("5", f"{central} collides most: more than {label}", "bars only",
                  f"collision rate, {central} - {label}", diff(collisions, "central", other),
                  +1, "pp"),
            Claim("5", f"{central} travels slowest: slower than {label}", "bars only",
                  f"travel time (all episodes, steps), {central} - {label}",
                  diff(travel, "central", other), +1, " steps"),
        ]  # fmt: skip
    blind = of("fedavg", yardstick_metric("full_throttle", "average_reward"))
    blind_collisions = of("fedavg", yardstick_metric("full_throttle", "collision_rate"))
    claims += [
        Claim("frl", f"{fed} tests better than full throttle", "not a claim of the paper",
              f"test reward, {fed} - full throttle, same seeds",
              paired(of("fedavg", test_reward), blind), +1),
        Claim("frl", f"{fed} collides less than full throttle", "not a claim of the paper",
              f"collision rate, {fed} - full throttle, same seeds",
              paired(of("fedavg", collisions), blind_collisions), -1,
              "pp"),
    ]  # fmt: skip
    rule = {
        name: of("fedavg", yardstick_metric(RULE, name))
        for name in ("average_reward", "collision_rate", "arrival_rate")
    }
    if any(rule.values()):  # runs tested beside the gap-acceptance driver
        arrivals = test_metric("arrival_rate")
        claims += [
            Claim("frl", f"{fed} tests better than the gap-acceptance driver",
                  "not a claim of the paper", f"test reward, {fed} - gap acceptance, same seeds",
                  paired(of("fedavg", test_reward), rule["average_reward"]), +1),
            Claim("frl", f"{fed} collides less than the gap-acceptance driver",
                  "not a claim of the paper",
                  f"collision rate, {fed} - gap acceptance, same seeds",
                  paired(of("fedavg", collisions), rule["collision_rate"]), -1, "pp"),
            Claim("frl", f"{fed} arrives more often than the gap-acceptance driver",
                  "not a claim of the paper",
                  f"arrival rate, {fed} - gap acceptance, same seeds",
                  paired(of("fedavg", arrivals), rule["arrival_rate"]), +1, "pp"),
        ]  # fmt: skip
    return claims


def fig6_claims(
    runs_by_interval: dict[int, list[RunRecord]], settings: CurveSettings, tested: bool = False
) -> list[Claim]:
    """Fig. 6: interval 2,000 is the best, against the best other interval, on the final
    training reward (the paper's measure) or, ``tested``, on the test reward (without
    exploration noise, on the final test's episodes)."""
    if tested:
        metric, measure = test_metric("average_reward"), "test reward"
        paper_best, paper_below = "6.84 at 2,000 (training reward)", "below 6.84 (training reward)"
    else:
        metric, measure = final_training_reward(settings), "final training reward"
        paper_best, paper_below = "6.84 at 2,000", "below 6.84"
    by_interval = {i: per_seed(runs, metric) for i, runs in runs_by_interval.items()}
    others = {i: v for i, v in by_interval.items() if i != PAPER_INTERVAL and v}
    paper = by_interval.get(PAPER_INTERVAL)
    # The best other interval is the one that comes closest to (or beats) interval 2,000
    # over the seeds the two share: means over different seeds would compare traffic too.
    differences = {i: paired(paper or {}, v) for i, v in others.items()}
    shared = {i: d for i, d in differences.items() if d is not None}
    if not shared:
        estimate, note = None, ""
    else:
        best = min(shared, key=lambda i: shared[i].mean)
        estimate = shared[best]
        seeds = ", ".join(str(s) for s in sorted(set(paper or {}) & set(others[best])))
        note = f"best other interval: {best:,}, over seeds {seeds}"
    claims = [
        Claim("6", f"aggregating every {PAPER_INTERVAL:,} steps is best, the curve biphasic",
              paper_best, f"{measure}, interval {PAPER_INTERVAL:,} - the best other interval",
              estimate, +1, note=note),
    ]  # fmt: skip
    # Biphasic: the shortest and the longest interval both end below 2,000.
    ends = {"short": min(others, default=None), "long": max(others, default=None)}
    for end, interval in ends.items():
        other = f"interval {interval:,}" if interval else f"the {end}est interval"
        estimate = paired(paper or {}, others[interval]) if interval else None
        claims.append(
            Claim("6", f"... an excessively {end} interval lowers the reward", paper_below,
                  f"{measure}, interval {PAPER_INTERVAL:,} - {other}", estimate, +1)
        )  # fmt: skip
    return claims


def fig3_claims(
    balanced: list[RunRecord],
    reference: list[RunRecord],
    slow: list[RunRecord] = (),  # type: ignore[assignment]
    reckless: list[RunRecord] = (),  # type: ignore[assignment]
) -> list[Claim]:
    """Fig. 3: alpha -0.05, lambda -10 against the reference reward, and the two weightings
    the paper discusses (``slow``: alpha -0.005, lambda -10; ``reckless``: alpha -0.05,
    lambda -1) against it."""
    steps, collisions = test_metric("average_episode_steps"), test_metric("collision_rate")

    def diff(metric: Metric, a: list[RunRecord], b: list[RunRecord]) -> Estimate | None:
        return paired(per_seed(a, metric), per_seed(b, metric))

    return [  # the paper's "travel time" counts every episode to its end
        Claim("3", "α=-0.05, λ=-10 drives faster than the reference reward", "-6.49%",
              "travel time (all episodes, steps), α=-0.05, λ=-10 - reference",
              diff(steps, balanced, reference), -1, " steps"),
        Claim("3", "... at slightly more collisions", "+1 pp",
              "collision rate, α=-0.05, λ=-10 - reference",
              diff(collisions, balanced, reference), +1, "pp"),
        Claim("3", "a light time cost (α=-0.005, λ=-10) prolongs the travel time",
              "74.83 steps", "travel time (all episodes, steps), α=-0.005, λ=-10 - "
              "α=-0.05, λ=-10", diff(steps, slow, balanced), +1, " steps"),
        Claim("3", "... and collides less: none", "0%",
              "collision rate, α=-0.005, λ=-10 - α=-0.05, λ=-10",
              diff(collisions, slow, balanced), -1, "pp"),
        Claim("3", "a light collision penalty (α=-0.05, λ=-1) raises collisions", "9%",
              "collision rate, α=-0.05, λ=-1 - α=-0.05, λ=-10",
              diff(collisions, reckless, balanced), +1, "pp"),
        Claim("3", "... and shortens the travel time (fewer arrive)", "44.87 steps",
              "travel time (all episodes, steps), α=-0.05, λ=-1 - α=-0.05, λ=-10",
              diff(steps, reckless, balanced), -1, " steps"),
    ]  # fmt: skip


def fig4_panel_claims(runs: list[RunRecord], settings: CurveSettings) -> list[Claim]:
    """Figs. 4 and 5's claims, with the convergence claims both ways: on the training curve
    and on the per-round test curve."""
    return in_figure_order(
        [
            *fig4_fig5_claims(runs, settings),
            *hold_claims(runs, settings, training_curve(settings), "training reward"),
            *hold_claims(runs, settings, per_round_test_curve, "tested return"),
        ]
    )


FIGURE_ORDER = ("3", "4", "5", "6", "frl")
"""The claims table's order: the paper's figures, then frl's own comparisons."""


def in_figure_order(claims: list[Claim]) -> list[Claim]:
    """``claims`` grouped by figure, each figure's rows in the order given."""
    return sorted(claims, key=lambda claim: FIGURE_ORDER.index(claim.figure))


def all_claims(collection: Collection, settings: CurveSettings) -> list[Claim]:
    """Every claim the runs of ``collection`` can test (rows marked not run otherwise)."""
    by_reward = {key: runs for key, (runs, _) in fig3_runs(collection).items()}
    balanced = by_reward.get(PAPER_REWARD_KEY)
    reference = [run for key, runs in by_reward.items() if key[0] == "reference" for run in runs]
    slow, reckless = (by_reward.get(("paper", alpha, lam)) or [] for alpha, lam in SLOW_RECKLESS)
    by_interval = {interval: runs for interval, (runs, _) in fig6_runs(collection).items()}
    return in_figure_order(
        [
            *fig3_claims(balanced or [], reference, slow, reckless),
            *fig4_panel_claims(collection.of("fig4"), settings),
            *fig6_claims(by_interval, settings),
            *fig6_claims(by_interval, settings, tested=True),
        ]
    )
