"""Per-figure summaries over seeds: the numbers the tables and plots of the report show.

Training curves. The paper's Fig. 4 "average reward" reaches 6-7, the scale of an
episode *return* (docs/scenario.md: a clean pass scores about 6.7), not of one step's
reward (about 0.15). The paper trains with Stable-Baselines3, whose logged
``rollout/ep_rew_mean`` is the mean return of the last 100 episodes; for Sep- and
FedAvg-DDPG it averages the three agents' curves. :func:`reward_curve` is that curve,
per step, from each client's training episodes. The per-step ``train/step_reward``
(moving average) is shown beside it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from frl.report.collect import Collection
from frl.report.measures import (
    Metric,
    PerSeed,
    paired,
    per_seed,
    task_metrics,
    test_metric,
    yardstick_metric,
)
from frl.report.runs import RunRecord
from frl.report.stats import (
    Estimate,
    band,
    episode_return_curve,
    first_crossing,
    first_hold,
    mean_ci,
)
from frl.report.stats import moving_average as _moving_average

SCHEMES: tuple[str, ...] = ("central", "separate", "fedavg")
SCHEME_LABELS = {"central": "Central-DDPG", "separate": "Sep-DDPG", "fedavg": "FedAvg-DDPG"}
TASKS: tuple[str, ...] = ("left", "straight", "right")
PAPER_INTERVAL = 2000
PAPER_REWARD = {"name": "paper", "alpha": -0.05, "lambda_": -10.0}
PAPER_REWARD_KEY = (PAPER_REWARD["name"], PAPER_REWARD["alpha"], PAPER_REWARD["lambda_"])
"""The paper reward as :func:`reward_key` gives it."""
FIG3_SETTINGS: tuple[tuple[str, float, float], ...] = (
    ("paper", -0.005, -1.0),
    ("paper", -0.005, -10.0),
    ("paper", -0.05, -1.0),
    ("paper", -0.05, -10.0),
    ("reference", -0.01, -1.0),
)
"""(name, alpha, lambda) of Fig. 3: the alpha x lambda grid and the reference reward."""


@dataclass(frozen=True)
class CurveSettings:
    """How training curves are smoothed and thresholded (stated in the report)."""

    episode_window: int = 100
    """Episodes in the trailing mean of returns (SB3's ``ep_rew_mean`` window)."""
    step_window: int = 500
    """Steps in the moving average of ``train/step_reward``."""
    threshold: float = 6.0
    """The paper's Fig. 4 benchmark reward."""


# ------------------------------------------------------------------- curves
def reward_curve(run: RunRecord, window: int) -> np.ndarray:
    """Mean over clients of each client's trailing ``window``-episode mean return, at
    steps 1..total_steps; NaN until every client has finished an episode."""
    if not run.episodes:
        return np.full(run.total_steps, np.nan)
    curves = [
        episode_return_curve(ep.end_step, ep.returns, run.total_steps, window)
        for ep in run.episodes.values()
    ]
    return np.mean(np.stack(curves), axis=0)


def final_training_reward(settings: CurveSettings) -> Metric:
    """A run's training curve (:func:`reward_curve`) at its last step."""
    return lambda run: float(reward_curve(run, settings.episode_window)[-1])


def step_reward_curve(run: RunRecord, window: int) -> np.ndarray:
    """``train/step_reward``, trailing ``window``-step moving average."""
    if run.step_rewards.size == 0:
        return np.zeros(0)
    return _moving_average(run.step_rewards, window)


def _padded(curve: np.ndarray, length: int) -> np.ndarray:
    """``curve`` cut or NaN-padded to ``length`` (a run whose curve is missing or short)."""
    out = np.full(length, np.nan)
    out[: min(length, curve.size)] = curve[:length]
    return out


@dataclass
class SchemeCurves:
    """One scheme's Fig. 4 numbers over its seeds."""

    scheme: str
    seeds: list[int]
    steps: np.ndarray
    reward_mean: np.ndarray
    reward_half: np.ndarray
    step_mean: np.ndarray
    step_half: np.ndarray
    crossings: list[int | None]
    """Per seed: first step the reward curve reaches the threshold."""
    crossing: Estimate | None
    """Over the seeds that crossed."""
    holds: list[int | None]
    """Per seed: the first step from which the reward curve holds the threshold."""
    mean_curve_crossing: int | None
    final_reward: Estimate
    final_step_reward: Estimate | None


def scheme_curves(runs: list[RunRecord], settings: CurveSettings) -> SchemeCurves:
    """Fig. 4 for one scheme: curves, bands, threshold steps and final rewards."""
    runs = sorted(runs, key=lambda r: r.seed)
    length = min(r.total_steps for r in runs)
    rewards = np.stack([reward_curve(r, settings.episode_window)[:length] for r in runs])
    steps_smoothed = np.stack(
        [_padded(step_reward_curve(r, settings.step_window), length) for r in runs]
    )
    reward_mean, reward_half = band(rewards)
    step_mean, step_half = band(steps_smoothed)
    # Before learning starts the actions are random: one lucky episode in a still short
    # window is not the agent reaching the threshold.
    crossings = [
        first_crossing(curve, settings.threshold, after=run.learning_starts)
        for run, curve in zip(runs, rewards, strict=True)
    ]
    crossed = [c for c in crossings if c is not None]
    finals = [float(curve[-1]) for curve in rewards if np.isfinite(curve[-1])]
    final_steps = [r.results["training"].get("final_step_reward") for r in runs]
    final_steps = [v for v in final_steps if v is not None]
    return SchemeCurves(
        scheme=runs[0].scheme,
        seeds=[r.seed for r in runs],
        steps=np.arange(1, length + 1),
        reward_mean=reward_mean,
        reward_half=reward_half,
        step_mean=step_mean,
        step_half=step_half,
        crossings=crossings,
        crossing=mean_ci(crossed) if crossed else None,
        holds=[first_hold(range(1, length + 1), curve, settings.threshold) for curve in rewards],
        mean_curve_crossing=first_crossing(
            reward_mean, settings.threshold, after=max(r.learning_starts for r in runs)
        ),
        final_reward=mean_ci(finals) if finals else Estimate(float("nan"), None, 0),
        final_step_reward=mean_ci(final_steps) if final_steps else None,
    )


def fig4(collection: Collection, settings: CurveSettings) -> dict[str, SchemeCurves]:
    """Per scheme present in ``fig4/``."""
    by_scheme = group(collection.of("fig4"), lambda r: r.scheme)
    return {s: scheme_curves(by_scheme[s], settings) for s in SCHEMES if s in by_scheme}


TESTED_CURVE_METRICS: tuple[str, ...] = ("average_reward", "collision_rate", "arrival_rate")
"""What the per-round test curve shows: a return alone would call a model that waits out
every episode nearly converged (the reward pays for waiting), so arrivals go beside it."""


@dataclass
class TestedCurve:
    """One scheme's per-round test curve (``round_test_episodes``) over its seeds."""

    scheme: str
    seeds: list[int]
    steps: list[int]
    """The rounds' last steps that every seed's run has."""
    metrics: dict[str, list[Estimate]]
    """Per metric of :data:`TESTED_CURVE_METRICS`, one estimate over the seeds a step."""
    holds: list[int | None]
    """Per seed: the first step from which the tested return holds the threshold."""
    episodes_per_task: int | None
    against_rule: dict[str, list[Estimate]] | None = None
    """Per metric, one estimate a step of the model's value minus the gap-acceptance
    rule's on the same round-test episodes, paired seed by seed; None unless every run
    has the rule tested on its curve's seeds."""


RULE = "gap_acceptance"
"""The yardstick a learned driver is paired against: the memoryless rule on the grid."""

COMMITTED_RULE = "committed_gap_acceptance"
"""The same rule told the distance to the stop line: it never waits inside the junction."""


def tested_curve(runs: list[RunRecord], settings: CurveSettings) -> TestedCurve:
    """The per-round test curve of one scheme's runs (each made with the curve on)."""
    runs = sorted(runs, key=lambda r: r.seed)
    by_run = [{m: dict(zip(*r.round_test_metric(m), strict=True)) for m in TESTED_CURVE_METRICS}
              for r in runs]  # fmt: skip
    shared = set.intersection(*(set(table["average_reward"]) for table in by_run))
    steps = sorted(shared)
    metrics = {
        metric: [mean_ci([table[metric][step] for table in by_run]) for step in steps]
        for metric in TESTED_CURVE_METRICS
    }
    rule = [(r.round_test_yardsticks.get(RULE) or {}).get("average") for r in runs]
    against_rule = None
    if all(rule):
        against_rule = {
            metric: [
                mean_ci([table[metric][step] - row[metric]  # type: ignore[index]
                         for table, row in zip(by_run, rule, strict=True)])
                for step in steps
            ]
            for metric in TESTED_CURVE_METRICS
        }  # fmt: skip
    returns = [table["average_reward"] for table in by_run]  # one per seed, in step order
    holds = [first_hold(list(r), list(r.values()), settings.threshold) for r in returns]
    episodes = {r.round_test_episodes for r in runs}
    return TestedCurve(
        scheme=runs[0].scheme,
        seeds=[r.seed for r in runs],
        steps=steps,
        metrics=metrics,
        holds=holds,
        episodes_per_task=episodes.pop() if len(episodes) == 1 else None,
        against_rule=against_rule,
    )


def _runs_with_tested_curve(collection: Collection) -> list[RunRecord]:
    """The ``fig4/`` runs made with the per-round test curve."""
    return [r for r in collection.of("fig4") if r.round_test_curve is not None]


def tested_curves(collection: Collection, settings: CurveSettings) -> dict[str, TestedCurve]:
    """Per scheme present in ``fig4/`` with the per-round test curve."""
    by_scheme = group(_runs_with_tested_curve(collection), lambda r: r.scheme)
    return {s: tested_curve(by_scheme[s], settings) for s in SCHEMES if s in by_scheme}


# ---------------------------------------------------------------- test tables
# The Fig. 5 subset of frl.episodes.METRIC_NAMES: the report tabulates these per task.
SUMMARISED_TEST_METRICS: tuple[str, ...] = (
    "average_reward",
    "collision_rate",
    "arrival_rate",
    "average_episode_steps",
    "average_travel_time",
)


@dataclass
class EvalSummary:
    """Test metrics over seeds: ``metrics[task][metric]``, task ``average`` included."""

    seeds: list[int]
    metrics: dict[str, dict[str, Estimate | None]] = field(default_factory=dict)


def eval_summary(runs: list[RunRecord]) -> EvalSummary | None:
    """Estimates of every test metric over the runs that were evaluated."""
    evaluated = sorted((r for r in runs if r.evaluation), key=lambda r: r.seed)
    if not evaluated:
        return None
    return _summary({r.seed: r.evaluation for r in evaluated})  # type: ignore[misc]


def _summary(tables: dict[int, dict[str, Any]]) -> EvalSummary:
    """Estimates over seeds of test tables (``{"per_task": ..., "average": ...}``)."""
    seeds = sorted(tables)
    summary = EvalSummary(seeds=seeds)
    for task in (*TASKS, "average"):
        rows = [task_metrics(tables[seed], task) for seed in seeds]
        if all(row is None for row in rows):
            continue
        summary.metrics[task] = {
            metric: _estimate([row.get(metric) for row in rows if row])
            for metric in SUMMARISED_TEST_METRICS
        }
    return summary


def fig5(collection: Collection) -> dict[str, EvalSummary]:
    by_scheme = group(collection.of("fig4"), lambda r: r.scheme)
    summaries = {s: eval_summary(by_scheme[s]) for s in SCHEMES if s in by_scheme}
    return {s: v for s, v in summaries.items() if v is not None}


def yardsticks_of(runs: list[RunRecord], on_round_tests: bool = False) -> dict[str, EvalSummary]:
    """The yardsticks ``runs`` were tested beside, over their distinct seeds: on the
    final test's seeds, or with ``on_round_tests`` on the per-round test curve's.

    Runs of one seed and one reward carry the same tables, so each seed counts once.
    Give runs of one reward only: its weights score the yardsticks, and the oracle picks
    its start by them, so its driving changes with the reward too.
    """
    tables: dict[str, dict[int, dict[str, Any]]] = {}
    for run in sorted(runs, key=lambda r: (r.seed, r.scheme)):
        tested = (
            run.round_test_yardsticks
            if on_round_tests
            else (run.evaluation or {}).get("yardsticks") or {}
        )
        for name, table in tested.items():
            tables.setdefault(name, {}).setdefault(run.seed, table)
    return {name: _summary(by_seed) for name, by_seed in tables.items()}


def tested_curve_yardsticks(collection: Collection) -> dict[str, EvalSummary]:
    """The yardsticks on the per-round test curve's own seeds, over the seeds of the
    ``fig4/`` runs with the curve; empty unless every such run has them."""
    tested = _runs_with_tested_curve(collection)
    if not tested or not all(r.round_test_yardsticks for r in tested):
        return {}
    return yardsticks_of(tested, on_round_tests=True)


def fig5_yardsticks(collection: Collection) -> dict[str, EvalSummary]:
    """The yardsticks of the ``fig4/`` runs (their test return is Fig. 4's reference)."""
    return yardsticks_of(collection.of("fig4"))


def fig3_yardsticks(collection: Collection) -> dict[str, EvalSummary]:
    """The yardsticks of Fig. 3's runs with the paper reward (:func:`fig3_runs`): their
    travel time and collision rate. The oracle waits for a clean start by the run's
    weights, longer where time costs less (alpha -0.005), so one reward must be chosen."""
    paper_reward_runs, _ = fig3_runs(collection).get(PAPER_REWARD_KEY, ([], False))
    return yardsticks_of(paper_reward_runs)


# --------------------------------------------------------------------- Fig. 6
@dataclass
class IntervalPoint:
    interval: int
    seeds: list[int]
    borrowed: bool
    """Its runs come from fig4/ (FedAvg at the paper's interval)."""
    final_reward: Estimate
    test_reward: Estimate | None
    total_bytes: Estimate | None
    over_full_throttle: Estimate | None = None
    """Test reward minus full throttle's, seed by seed (each run's own yardstick)."""
    final_by_seed: PerSeed = field(default_factory=dict)
    test_by_seed: PerSeed = field(default_factory=dict)
    """The same two measures per seed, to set intervals side by side on the seeds they
    share (interval 2,000 borrows fig4's runs, which may have more seeds)."""


def fig6_runs(collection: Collection) -> dict[int, tuple[list[RunRecord], bool]]:
    """FedAvg runs per interval, by interval, each with whether they are borrowed: fig6/
    runs, plus fig4/'s FedAvg runs for the interval(s) fig6/ does not hold."""
    own = group([r for r in collection.of("fig6") if r.scheme == "fedavg"], lambda r: r.interval)
    borrowed = group(
        [r for r in collection.of("fig4") if r.scheme == "fedavg" and is_paper_reward(r)],
        lambda r: r.interval,
    )
    return {
        interval: (sorted(own.get(interval) or borrowed[interval], key=lambda r: r.seed),
                   interval not in own)
        for interval in sorted(set(own) | set(borrowed))
    }  # fmt: skip


def fig6(collection: Collection, settings: CurveSettings) -> list[IntervalPoint]:
    """FedAvg per interval (:func:`fig6_runs`)."""
    points = []
    for interval, (runs, borrowed) in fig6_runs(collection).items():
        final_by_seed = per_seed(runs, final_training_reward(settings))
        finals = list(final_by_seed.values())
        test_by_seed = per_seed(runs, test_metric("average_reward"))
        total_bytes = [r.results["communication"].get("total_bytes") for r in runs]
        points.append(
            IntervalPoint(
                interval=interval,
                seeds=[r.seed for r in runs],
                borrowed=borrowed,
                final_reward=mean_ci(finals) if finals else Estimate(float("nan"), None, 0),
                test_reward=_estimate(list(test_by_seed.values())),
                total_bytes=_estimate(total_bytes),
                over_full_throttle=paired(
                    test_by_seed,
                    per_seed(runs, yardstick_metric("full_throttle", "average_reward")),
                ),
                final_by_seed=final_by_seed,
                test_by_seed=test_by_seed,
            )
        )
    return points


def fig6_yardsticks(collection: Collection) -> dict[str, EvalSummary]:
    """The yardsticks of every run Fig. 6 draws (:func:`fig6_runs`), over their seeds."""
    runs = [run for interval_runs, _ in fig6_runs(collection).values() for run in interval_runs]
    return yardsticks_of(runs)


# --------------------------------------------------------------------- Fig. 3
@dataclass
class RewardPoint:
    name: str
    alpha: float
    lambda_: float
    scheme: str
    seeds: list[int]
    borrowed: bool
    summary: EvalSummary | None

    @property
    def label(self) -> str:
        if self.name == "reference":
            return "reference [22]"
        return f"α={self.alpha:g}, λ={self.lambda_:g}"


def fig3_runs(
    collection: Collection,
) -> dict[tuple[str, float, float], tuple[list[RunRecord], bool]]:
    """Runs per reward setting (:func:`reward_key`), in Fig. 3's order, each with whether
    they are borrowed: fig3/ runs, plus fig4/'s runs of the same scheme with the paper
    reward for that setting when fig3/ does not hold it."""
    own = collection.of("fig3")
    schemes = {r.scheme for r in own}
    borrowed = [r for r in collection.of("fig4") if r.scheme in schemes and is_paper_reward(r)]
    own_groups = group(own, reward_key)
    borrowed_groups = group(borrowed, reward_key)
    keys = sorted(set(own_groups) | set(borrowed_groups), key=_fig3_order)
    return {key: (own_groups.get(key) or borrowed_groups[key], key not in own_groups)
            for key in keys}  # fmt: skip


def fig3(collection: Collection) -> list[RewardPoint]:
    """Per reward setting (:func:`fig3_runs`)."""
    points = []
    for key, (runs, borrowed) in fig3_runs(collection).items():
        points.append(
            RewardPoint(
                name=key[0],
                alpha=key[1],
                lambda_=key[2],
                scheme=", ".join(sorted({r.scheme for r in runs})),
                seeds=sorted(r.seed for r in runs),
                borrowed=borrowed,
                summary=eval_summary(runs),
            )
        )
    return points


# ------------------------------------------------------------------ helpers
def group(runs: list[RunRecord], key: Any) -> dict[Any, list[RunRecord]]:
    """``runs`` by ``key(run)``, in their order."""
    groups: dict[Any, list[RunRecord]] = {}
    for run in runs:
        groups.setdefault(key(run), []).append(run)
    return groups


def reward_key(run: RunRecord) -> tuple[str, float, float]:
    reward = run.reward
    return (
        str(reward.get("name", "paper")),
        float(reward.get("alpha", PAPER_REWARD["alpha"])),
        float(reward.get("lambda_", PAPER_REWARD["lambda_"])),
    )


def is_paper_reward(run: RunRecord) -> bool:
    return reward_key(run) == PAPER_REWARD_KEY


def _fig3_order(key: tuple[str, float, float]) -> tuple[int, tuple[str, float, float]]:
    for index, (name, alpha, lam) in enumerate(FIG3_SETTINGS):
        if key[0] == name and np.isclose(key[1], alpha) and np.isclose(key[2], lam):
            return index, key
    return len(FIG3_SETTINGS), key


def _estimate(values: list[Any]) -> Estimate | None:
    numbers = [float(v) for v in values if v is not None]
    return mean_ci(numbers) if numbers else None
