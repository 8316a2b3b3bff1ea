"""The markdown of ``docs/results.md``: generated tables between markers, prose kept.

Each generated block sits between ``<!-- frl.report:begin NAME -->`` and
``<!-- frl.report:end NAME -->``. Rebuilding replaces only those blocks, so the
hand-written discussion around them survives; a block missing from the file is
appended at its end.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

import numpy as np

from frl.report.aggregate import (
    FIG3_SETTINGS,
    PAPER_INTERVAL,
    SCHEME_LABELS,
    SCHEMES,
    TASKS,
    TESTED_CURVE_METRICS,
    CurveSettings,
    EvalSummary,
    IntervalPoint,
    RewardPoint,
    SchemeCurves,
    TestedCurve,
    fig3_runs,
    fig6_runs,
)
from frl.report.claims import Claim
from frl.report.collect import Collection
from frl.report.runs import RunRecord
from frl.report.stats import CONFIDENCE, Estimate, mean_ci

NOT_RUN = "not run yet"
PAPER_CROSSING = {"fedavg": 4593, "separate": 6068, "central": 9841}
PAPER_SPEEDUP = {"separate": 32.11, "central": 114.26}
PAPER_FINAL_GAIN = 21.00
PAPER_FIG6_INTERVALS = (250, 500, 1000, 2000, 2500, 5000, 10000)
PAPER_FIG6_BEST = (2000, 6.84)

TEMPLATE = """# Reproducing the paper's results

Built by `python -m frl.report`. The blocks between `<!-- frl.report:begin ... -->` and
`<!-- frl.report:end ... -->` are rewritten on every build; everything else is
hand-written and kept.

## The paper's claims

{claims}

## Summary

_Not written yet: what reproduced and what did not, from the tables below._

## How the numbers were made

{method}

## Fig. 3: reward tuning

{fig3}

_Discussion not written yet._

## Fig. 4: convergence

{fig4}

### Fig. 4 without exploration noise: the per-round test curve

{fig4-tested}

_Discussion not written yet._

## Fig. 5: test performance per task

{fig5}

_Discussion not written yet._

## Fig. 6: aggregation interval

{fig6}

_Discussion not written yet._

## Figs. 4 and 5 at the default budget, without the collision budget

{claims-data-budget}

{fig4-data-budget}

{fig4-tested-data-budget}

{fig5-data-budget}

{runs-data-budget}

## Figs. 4 and 5 at the default budget, with the collision budget

{claims-collision-budget}

{fig4-collision-budget}

{fig4-tested-collision-budget}

{fig5-collision-budget}

{runs-collision-budget}

## Figs. 4 and 5 with the cost critic on each episode's costs to go

{claims-costs-to-go}

{fig4-costs-to-go}

{fig4-tested-costs-to-go}

{fig5-costs-to-go}

{runs-costs-to-go}

## Figs. 4 and 5 at the default: the critics at three times the learning rate

{claims-faster-critics}

{fig4-faster-critics}

{fig4-tested-faster-critics}

{fig5-faster-critics}

{runs-faster-critics}

## Figs. 4 and 5 with the guided agent

{claims-guided}

{fig4-guided}

{fig4-tested-guided}

{fig5-guided}

{runs-guided}

## Figs. 4 and 5 with the paper's agent (Table II)

{claims-paper-agent}

{fig4-paper-agent}

{fig4-tested-paper-agent}

{fig5-paper-agent}

{runs-paper-agent}

## The studies' run sets

{studies}

## Runs

{runs}
"""


def block(name: str, body: str) -> str:
    return f"<!-- frl.report:begin {name} -->\n{body.strip()}\n<!-- frl.report:end {name} -->"


def merge(existing: str | None, blocks: dict[str, str]) -> str:
    """``existing`` with its generated blocks replaced (the template if None)."""
    if existing is None:
        names = re.findall(r"\{([\w-]+)\}", TEMPLATE)
        existing = TEMPLATE
        for name in names:
            existing = existing.replace(f"{{{name}}}", block(name, f"_{NOT_RUN}_"))
    text = existing
    for name, body in blocks.items():
        begin, end = (re.escape(f"<!-- frl.report:{m} {name} -->") for m in ("begin", "end"))
        pattern = re.compile(f"{begin}.*?{end}", re.DOTALL)
        if pattern.search(text):
            text = pattern.sub(lambda _m, n=name, b=body: block(n, b), text, count=1)
        else:
            text = text.rstrip("\n") + "\n\n" + block(name, body) + "\n"
    return text


# ----------------------------------------------------------------- formatting
def fmt(
    estimate: Estimate | None, digits: int = 2, percent: bool = False, unit: str | None = None
) -> str:
    """``mean ± half`` (95% CI), ``mean (n=1)``, or the not-run marker; ``unit`` follows
    the number (``%`` where ``percent`` unless given)."""
    if estimate is None or estimate.n == 0 or not np.isfinite(estimate.mean):
        return "–"
    scale = 100.0 if percent else 1.0
    unit = ("%" if percent else "") if unit is None else unit
    mean = f"{estimate.mean * scale:,.{digits}f}"
    if estimate.half_width is None:
        return f"{mean}{unit} (n=1)"
    return f"{mean} ± {estimate.half_width * scale:,.{digits}f}{unit}"


def table(header: Iterable[str], rows: Iterable[Iterable[object]]) -> str:
    header = list(header)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _seeds(seeds: list[int]) -> str:
    return f"{len(seeds)} ({', '.join(str(s) for s in seeds)})"


def _pct_change(new: float, old: float) -> str:
    if not (np.isfinite(new) and np.isfinite(old)) or old == 0:
        return "–"
    return f"{(new - old) / abs(old) * 100:+.2f}%"


def _reward_gain(new: float, old: float) -> str:
    """Relative gain over a positive baseline reward; the plain difference otherwise, since
    a percentage of a negative reward reads backwards."""
    if not (np.isfinite(new) and np.isfinite(old)):
        return "–"
    if old > 0:
        return _pct_change(new, old)
    return f"{new - old:+.2f} (difference: baseline <= 0)"


def _image(path: str | None, alt: str) -> str:
    return f"![{alt}]({path})\n\n" if path else ""


# ------------------------------------------------------------------- blocks
def claims_block(claims: list[Claim]) -> str:
    """One row per claim of the paper: ours, the paper's, the verdict."""
    rows = []
    for c in claims:
        percent = c.unit in ("pp", "%")
        digits = c.digits
        if digits is None:
            digits = 1 if percent or c.unit == " steps" else 2
        ours = fmt(c.ours, digits, percent=percent, unit=" pp" if c.unit == "pp" else c.unit)
        measure = f"{c.measure} ({c.note})" if c.note else c.measure
        rows.append([c.figure, c.claim, c.paper, measure, ours, c.verdict])
    header = ["Fig.", "claim", "paper", "our measure (paired over seeds)", "ours: mean ± 95% CI",
              "verdict"]  # fmt: skip
    return (
        table(header, rows)
        + "\n\nEach difference is taken seed by seed (the runs of one seed share its "
        "traffic), then averaged with a 95% t interval over the seeds. Significant: the "
        "interval excludes zero. The paper tests one run per setting and gives no intervals."
    )


def method_block(collection: Collection, settings: CurveSettings) -> str:
    level = f"{CONFIDENCE:.0%}"
    fig3_borrows = any(borrowed for _, borrowed in fig3_runs(collection).values())
    fig6_borrows = any(borrowed for _, borrowed in fig6_runs(collection).values())
    fig3_source = (
        "its paper-reward point shared with Fig. 4's runs"
        if fig3_borrows
        else "every point from its own runs"
    )
    fig6_source = (
        f"Fig. 6's interval {PAPER_INTERVAL} is Fig. 4's FedAvg runs"
        if fig6_borrows
        else "Fig. 6 has its own runs at every interval"
    )
    return f"""- Source: `{collection.root}`, {collection.count} finished run(s); the runs
  table at the end gives each one's seed, wall time (training, summed over the sessions
  of a resumed run, plus testing) and commit.
- Every number is a mean over seeds with a {level} confidence interval from the
  t distribution with n-1 degrees of freedom (`mean ± half-width`); `(n=1)`: one seed,
  no interval. `–`: no data; "{NOT_RUN}": the runs do not exist yet.
- Training reward (Figs. 4 and 6): at each step, the mean return of each agent's last
  {settings.episode_window} training episodes (Stable-Baselines3's `ep_rew_mean`, the
  paper's tool), averaged over the agents; the paper's reward scale (a clean pass scores
  about 6.7). "First step >= {settings.threshold:g}" is the first step at which this curve
  reaches {settings.threshold:g}, counted only after the warm-up (`agent.learning_starts`
  steps of random actions, 1,000 in Table II), where a window of one or two lucky
  episodes can reach it; "holds {settings.threshold:g} from" is the first step from which
  it stays at or above {settings.threshold:g} to the end, the paper's "reaches" read as
  converged; "final" is its value at the last step. The per-step
  `train/step_reward` ({settings.step_window}-step moving average) is plotted beside it.
- Tested curve (Fig. 4 without exploration noise, runs made with `round_test_episodes`):
  after every round, the deployed model tested with exploration off on a few episodes
  per task of fixed seeds, none of them a final test seed; its holding step is read the
  same way, at a round's resolution.
- Test metrics (Figs. 3 and 5): 100 episodes per task after training, exploration off.
  "Travel time (all)" counts every episode to its end, collisions and time-outs
  included (the paper's convention; it makes collisions look fast); "travel time
  (arrived)" averages arrived episodes only.
- Fig. 3 is trained with the scheme named in its table (Central-DDPG by default: one
  agent, a random task per episode, tested on every task), {fig3_source};
  {fig6_source}."""


def yardstick_returns(yardsticks: dict[str, EvalSummary] | None) -> str:
    """A sentence giving each yardstick's average test return (Fig. 4's reference lines)."""
    parts = [
        f"{name.replace('_', ' ')} {fmt(summary.metrics.get('average', {}).get('average_reward'))}"
        for name, summary in (yardsticks or {}).items()
    ]
    if not parts:
        return ""
    return (
        "\n\nReference lines: the yardsticks' test return, averaged over the tasks, on the "
        f"same seeds: {', '.join(parts)}. A training curve is measured with exploration "
        "noise on, so it sits somewhat below what the same agent scores in its test."
    )


def fig4_block(
    curves: dict[str, SchemeCurves],
    settings: CurveSettings,
    image: str | None,
    yardsticks: dict[str, EvalSummary] | None = None,
) -> str:
    if not curves:
        return f"_{NOT_RUN}_ (needs `fig4/` runs: `python -m frl.reproduce --figures fig4`)."
    threshold = f"{settings.threshold:g}"
    rows = []
    for scheme in SCHEMES:
        c = curves.get(scheme)
        if c is None:
            rows.append(
                [SCHEME_LABELS[scheme], NOT_RUN, "", "", "", "", f"{PAPER_CROSSING[scheme]:,}",
                 "", ""]
            )  # fmt: skip
            continue
        crossed = sum(x is not None for x in c.crossings)
        per_seed = ", ".join("never" if x is None else f"{x:,}" for x in c.crossings)
        held = sum(x is not None for x in c.holds)
        holds = ", ".join("never" if x is None else f"{x:,}" for x in c.holds)
        mean_cross = "never" if c.mean_curve_crossing is None else f"{c.mean_curve_crossing:,}"
        rows.append(
            [
                SCHEME_LABELS[scheme],
                _seeds(c.seeds),
                fmt(c.crossing, 0),
                f"{crossed}/{len(c.seeds)}: {per_seed}",
                f"{held}/{len(c.seeds)}: {holds}",
                mean_cross,
                f"{PAPER_CROSSING[scheme]:,}",
                fmt(c.final_reward),
                fmt(c.final_step_reward, 4),
            ]
        )
    text = _image(image, "Fig. 4") + table(
        [
            "scheme",
            "seeds",
            f"first step >= {threshold} (seeds that crossed)",
            "crossed: per seed",
            f"holds {threshold} from: per seed",
            "mean curve crosses at",
            "paper",
            "final reward",
            "final train/step_reward (last 10%)",
        ],
        rows,
    )
    fed = curves.get("fedavg")
    comparisons = []
    for other in ("separate", "central"):
        o = curves.get(other)
        if fed is None or o is None:
            comparisons.append(
                [
                    SCHEME_LABELS[other],
                    NOT_RUN,
                    f"{PAPER_SPEEDUP[other]:.2f}%",
                    NOT_RUN,
                    f"{PAPER_FINAL_GAIN:.2f}%",
                ]
            )
            continue
        speed = (
            _pct_change(o.mean_curve_crossing, fed.mean_curve_crossing)
            if o.mean_curve_crossing and fed.mean_curve_crossing
            else "–"
        )
        comparisons.append(
            [
                SCHEME_LABELS[other],
                speed,
                f"+{PAPER_SPEEDUP[other]:.2f}%",
                _reward_gain(fed.final_reward.mean, o.final_reward.mean),
                f"+{PAPER_FINAL_GAIN:.2f}%",
            ]
        )
    text += "\n\nFedAvg-DDPG against each baseline (speed-up: the baseline's crossing step of "
    text += "the mean curve over FedAvg's, minus 1; gain: final reward of FedAvg over the "
    text += "baseline's, minus 1, where the baseline's is positive):\n\n"
    text += table(
        ["baseline", "speed-up (ours)", "paper", "final-reward gain (ours)", "paper"], comparisons
    )
    return text + yardstick_returns(yardsticks)


TESTED_METRIC_LABELS = {
    "average_reward": "tested return",
    "collision_rate": "collisions",
    "arrival_rate": "arrivals",
}


def _fmt_tested(metric: str, estimate: Estimate | None, unit: str | None = None) -> str:
    """A tested-curve metric: the return to two digits, the rates in percent to one."""
    rate = metric != "average_reward"
    return fmt(estimate, 1 if rate else 2, percent=rate, unit=unit)


RULE_GAP_ROWS = {
    "average_reward": ("tested return - gap acceptance", None),
    "collision_rate": ("collisions - gap acceptance", " pp"),
}
"""The rows that pair each round's test with the rule on the same episodes."""


def fig4_tested_block(
    curves: dict[str, TestedCurve],
    settings: CurveSettings,
    image: str | None,
    yardsticks: dict[str, EvalSummary] | None = None,
    on_curve_seeds: bool = False,
) -> str:
    """Fig. 4 without exploration noise: each scheme's deployed model tested every round.

    ``yardsticks`` are the reference lines: on the curve's own seeds where
    ``on_curve_seeds``, else on the final test's."""
    if not curves:
        return (
            f"_{NOT_RUN}_ (needs `fig4/` runs made with the per-round test curve: "
            "`round_test_episodes=N`, on in the fig4 preset)."
        )
    threshold = f"{settings.threshold:g}"
    text = _image(image, "Fig. 4, tested every round")
    for scheme in SCHEMES:
        c = curves.get(scheme)
        if c is None:
            text += f"**{SCHEME_LABELS[scheme]}**: {NOT_RUN}.\n\n"
            continue
        holds = ", ".join(
            f"seed {seed}: {'never' if step is None else f'{step:,}'}"
            for seed, step in zip(c.seeds, c.holds, strict=True)
        )
        text += (
            f"**{SCHEME_LABELS[scheme]}** over {len(c.seeds)} seed{'s' * (len(c.seeds) > 1)}. "
            f"The step from which the tested return holds {threshold}: {holds}.\n\n"
        )
        rows = [
            [TESTED_METRIC_LABELS[metric], *(_fmt_tested(metric, e) for e in estimates)]
            for metric, estimates in c.metrics.items()
        ]
        for metric, (label, unit) in RULE_GAP_ROWS.items() if c.against_rule else ():
            gaps = c.against_rule[metric]  # type: ignore[index]
            rows.append([label, *(_fmt_tested(metric, e, unit) for e in gaps)])
        text += table(["step", *(f"{step:,}" for step in c.steps)], rows) + "\n\n"
    episodes = {c.episodes_per_task for c in curves.values()}
    per_task = f"{episodes.pop()} episodes" if len(episodes) == 1 else "a few episodes"
    text += (
        f"After every round the deployed model (FedAvg's global model, each Sep-DDPG "
        f"vehicle on its own task, Central-DDPG's one agent) is tested with exploration off "
        f"on {per_task} per task, the same fixed seeds every round, none of them a final test "
        f"seed. One point a round: a hold can only be placed at a round's end, a resolution "
        f"of one interval. Read arrivals beside the return: the reward pays for moving, so "
        f"a car that creeps and never arrives scores well (a constant 0.02 m/s^2 on seed 0's "
        f"test episodes: 5.62, with 13.7% collisions and no arrival), while one that stands "
        f"still scores 0."
    )
    parts = [
        f"{name.replace('_', ' ')} "
        + " / ".join(_fmt_tested(metric, summary.metrics.get("average", {}).get(metric))
                     for metric in TESTED_CURVE_METRICS)
        for name, summary in (yardsticks or {}).items()
    ]  # fmt: skip
    if parts and on_curve_seeds:
        text += (
            "\n\nReference lines: the yardsticks on the round tests' own seeds (return / "
            f'collisions / arrivals): {", ".join(parts)}. The rows "- gap acceptance" '
            "pair each seed's model with the rule on the same episodes, round by round "
            "(`python -m frl.evaluate RUN_DIR --round-tests` adds the rule to a run made "
            "before it was tested there)."
        )
    elif parts:
        text += (
            "\n\nReference lines: the yardsticks on the final test's seeds (return / "
            f"collisions / arrivals): {', '.join(parts)}. The round tests drive other "
            "seeds, so the lines are a guide, not a pairing."
        )
    return text


def fig5_block(
    summaries: dict[str, EvalSummary],
    image: str | None,
    yardsticks: dict[str, EvalSummary] | None = None,
) -> str:
    if not summaries:
        return f"_{NOT_RUN}_ (needs evaluated `fig4/` runs)."
    rows = []
    labelled = [(SCHEME_LABELS[scheme], summaries.get(scheme)) for scheme in SCHEMES]
    labelled += [
        (f"{name.replace('_', ' ')} (yardstick)", summary)
        for name, summary in (yardsticks or {}).items()
    ]
    for label, s in labelled:
        for task in (*TASKS, "average"):
            if s is None:
                rows.append([label, task, NOT_RUN, "", "", "", "", ""])
                continue
            m = s.metrics.get(task, {})
            rows.append(
                [
                    label,
                    task,
                    len(s.seeds),
                    fmt(m.get("average_reward")),
                    fmt(m.get("collision_rate"), 1, percent=True),
                    fmt(m.get("arrival_rate"), 1, percent=True),
                    fmt(m.get("average_episode_steps"), 1),
                    fmt(m.get("average_travel_time"), 1),
                ]
            )
    text = _image(image, "Fig. 5") + table(
        [
            "scheme",
            "task",
            "seeds",
            "test reward",
            "collision rate",
            "arrival rate",
            "travel time (all)",
            "travel time (arrived)",
        ],
        rows,
    )
    text += (
        "\n\nThe paper gives Fig. 5 as bars without numbers in its text. Its claims: "
        "Central-DDPG is worst on all three metrics; FedAvg-DDPG beats Sep-DDPG on all "
        "metrics and markedly lowers collisions on every task."
    )
    if yardsticks:
        text += (
            " The yardstick rows (frl.policies) were tested on the same seeds and traffic as "
            "the schemes: full throttle never brakes; the oracle waits with hindsight for a "
            "clean start, then goes at full throttle (docs/scenario.md)."
        )
    return text


def fig6_block(
    points: list[IntervalPoint],
    settings: CurveSettings,
    image: str | None,
    yardsticks: dict[str, EvalSummary] | None = None,
) -> str:
    if not points:
        return f"_{NOT_RUN}_ (needs `fig6/` runs or FedAvg runs in `fig4/`)."
    by_interval = {p.interval: p for p in points}
    # Runs tested before the yardsticks existed (the first edition) have no gap to show.
    gaps = any(p.over_full_throttle is not None for p in points)
    rows = []
    for interval in sorted(set(PAPER_FIG6_INTERVALS) | set(by_interval)):
        paper = f"{PAPER_FIG6_BEST[1]} (best)" if interval == PAPER_FIG6_BEST[0] else "–"
        p = by_interval.get(interval)
        if p is None:
            rows.append([f"{interval:,}", NOT_RUN, "", "", *([""] * gaps), "", paper])
            continue
        mb = "–" if p.total_bytes is None else f"{p.total_bytes.mean / 1e6:,.1f}"
        seeds = _seeds(p.seeds) + (" (fig4)" if p.borrowed else "")
        gap = [fmt(p.over_full_throttle)] * gaps
        rows.append(
            [f"{interval:,}", seeds, fmt(p.final_reward), fmt(p.test_reward), *gap, mb, paper]
        )
    header = ["interval", "seeds", "final training reward", "test reward"]
    header += ["test reward - full throttle (same seeds)"] * gaps
    text = _image(image, "Fig. 6") + table([*header, "communication (MB)", "paper"], rows)
    text += yardstick_returns(yardsticks)
    return text + best_interval(points)


def best_interval(points: list[IntervalPoint]) -> str:
    """The interval with the best final training reward (the paper's measure) and the one
    with the best test reward, over the seeds every interval has: means over different
    seeds differ by their traffic as much as by the interval."""
    finite = [p for p in points if np.isfinite(p.final_reward.mean)]
    if len(finite) < 2:  # a best of one is no finding
        return ""
    paper = f"{PAPER_FIG6_BEST[0]:,} with {PAPER_FIG6_BEST[1]}"
    shared = sorted(set.intersection(*(set(p.final_by_seed) for p in finite)))
    if not shared:
        return (
            "\n\nNo best interval is named: no seed has run at every interval. "
            f"The paper's best: {paper}."
        )
    parts = []
    measures = {"final training reward": lambda p: p.final_by_seed,
                "test reward": lambda p: p.test_by_seed}  # fmt: skip
    for measure, by_seed in measures.items():
        if all(set(shared) <= set(by_seed(p)) for p in finite):
            means = {p.interval: mean_ci([by_seed(p)[s] for s in shared]) for p in finite}
            best = max(means, key=lambda i: means[i].mean)
            parts.append(f"by {measure} {best:,} ({fmt(means[best])})")
    return (
        "\n\nBest interval over the seeds every interval has "
        f"({', '.join(str(s) for s in shared)}): {' and '.join(parts)}; the paper: {paper}, "
        "a biphasic curve."
    )


def fig3_block(
    points: list[RewardPoint],
    image: str | None,
    yardsticks: dict[str, EvalSummary] | None = None,
) -> str:
    if not points:
        return f"_{NOT_RUN}_ (needs `fig3/` runs)."
    paper = {
        ("paper", -0.005, -10.0): "74.83 steps, 0% collisions",
        ("paper", -0.05, -1.0): "44.87 steps, 9% collisions",
        ("paper", -0.05, -10.0): "6.49% faster than reference, +1 pp collisions",
        ("paper", -0.005, -1.0): "–",
        ("reference", -0.01, -1.0): "–",
    }
    found = {(p.name, p.alpha, p.lambda_): p for p in points}
    rows = []
    for key in [*FIG3_SETTINGS, *[k for k in found if k not in FIG3_SETTINGS]]:
        p = found.get(key)
        label = "reference [22]" if key[0] == "reference" else f"α={key[1]:g}, λ={key[2]:g}"
        if p is None:
            rows.append([label, NOT_RUN, "", "", "", "", paper.get(key, "–")])
            continue
        m = p.summary.metrics.get("average", {}) if p.summary else {}
        seeds = _seeds(p.seeds) + (" (fig4)" if p.borrowed else "")
        rows.append(
            [
                label,
                p.scheme,
                seeds,
                fmt(m.get("average_episode_steps"), 2),
                fmt(m.get("average_travel_time"), 2),
                fmt(m.get("collision_rate"), 1, percent=True),
                paper.get(key, "–"),
            ]
        )
    for name, summary in (yardsticks or {}).items():
        m = summary.metrics.get("average", {})
        rows.append(
            [
                f"{name.replace('_', ' ')} (yardstick)",
                "–",
                _seeds(summary.seeds),
                fmt(m.get("average_episode_steps"), 2),
                fmt(m.get("average_travel_time"), 2),
                fmt(m.get("collision_rate"), 1, percent=True),
                "–",
            ]
        )
    text = _image(image, "Fig. 3") + table(
        [
            "reward",
            "scheme",
            "seeds",
            "travel time (all)",
            "travel time (arrived)",
            "collision rate",
            "paper",
        ],
        rows,
    )
    balanced, reference = found.get(("paper", -0.05, -10.0)), found.get(("reference", -0.01, -1.0))
    if balanced and reference and balanced.summary and reference.summary:
        b, r = balanced.summary.metrics["average"], reference.summary.metrics["average"]
        tt_b, tt_r = b.get("average_episode_steps"), r.get("average_episode_steps")
        cr_b, cr_r = b.get("collision_rate"), r.get("collision_rate")
        if tt_b and tt_r and cr_b and cr_r:
            text += (
                f"\n\nα=-0.05, λ=-10 against the reference reward: travel time (all) "
                f"{_pct_change(tt_b.mean, tt_r.mean)}, collision rate "
                f"{(cr_b.mean - cr_r.mean) * 100:+.1f} pp (paper: -6.49%, +1 pp)."
            )
    if yardsticks:
        text += (
            "\n\nThe yardstick rows are those tested beside the α=-0.05, λ=-10 runs, on the "
            "same seeds. The oracle waits for a clean start by the run's reward weights, so "
            "under another reward it drives differently (under α=-0.005 it waits longer)."
        )
    return text


def runs_block(collection: Collection) -> str:
    rows = []
    walls: list[float] = []
    commits: set[str] = set()
    for sweep, runs in sorted(collection.runs.items()):
        # by interval first: by name alone, "interval1000" sorts before "interval250"
        for run in sorted(runs, key=lambda r: (r.interval, r.name)):
            wall = run.wall_time_s
            if wall is not None:
                walls.append(wall)
            commit = run.git_commit
            if commit:
                commits.add(commit[:10])
            rows.append(
                [
                    sweep,
                    run.name,
                    run.scheme,
                    run.seed,
                    f"{run.interval:,}",
                    _reward_label(run),
                    _hours(wall),
                    run.config.get("cores") or "all",
                    (commit or "–")[:10],
                    "yes" if run.evaluation else "no",
                ]
            )
    header = ["sweep", "run", "scheme", "seed", "interval", "reward", "wall time", "cores",
              "commit", "tested"]  # fmt: skip
    text = table(header, rows)
    text += (
        f"\n\nTotal wall time of the {len(rows)} finished runs: {_hours(sum(walls))}, the "
        "sum of their wall times. Runs on a share of the cores ran side by side "
        "(`frl.reproduce --jobs`), so less time passed than that, and each took longer "
        f"than it would alone. Commits: {', '.join(sorted(commits)) or '–'}."
    )
    unfinished = [p for paths in collection.unfinished.values() for p in paths]
    if unfinished:
        text += "\n\nUnfinished (not used): " + ", ".join(
            f"`{p.parent.name}/{p.name}`" for p in unfinished
        )
    return text


def _reward_label(run: RunRecord) -> str:
    reward = run.reward
    if not reward:
        return "–"
    if reward.get("name") == "reference":
        return "reference"
    return f"α={float(reward.get('alpha')):g}, λ={float(reward.get('lambda_')):g}"


def _hours(seconds: float | None) -> str:
    if seconds is None:
        return "–"
    if seconds < 3600:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.2f} h"
