"""Agent options that frl retired: measured by a study and found not to help, or never
measured and used by no preset.

A config or checkpoint may still name one at the value that switched it off: it loads
as if the key were absent, so every run and checkpoint made before the retirement still
reads. Any other value is refused in one line that names the key, the study that measured
it (a section of docs/studies.md) and the commit that retired it, where the code is still
there to read.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

RETIRING_COMMIT = "7ff57ca"
"""The commit that removed the first options below (``git show`` it to read their code)."""


@dataclass(frozen=True)
class RetiredOption:
    off: Any
    """The value that left the agent as it is without the option."""
    study: str | None
    """Where docs/studies.md gives what it measured; None: no study measured it."""
    commit: str = RETIRING_COMMIT
    """The commit that removed it."""
    idle_when: tuple[str, Any] | None = None
    """``(key, value)``: where the same options set ``key`` to ``value`` the option did
    nothing at any value (a Q-filter with no imitation term to filter), so it loads."""


_DRIVE_WELL = '"Agents that drive well"'
_LEVERS = '"The rule as a teacher, the task as an input, prioritised replay"'
_UNMEASURED_COMMIT = "bbf4ecc"
_THIRD_COMMIT = "c76bc5e"
_BUDGET = '"A collision budget"'
_BUDGET_COMMIT = "60f3304"
_KEEPABLE_BUDGET = '"A budget the car can keep"'
_KEEPABLE_BUDGET_COMMIT = "f5359cd"

RETIRED_OPTIONS: dict[str, RetiredOption] = {
    "action_repeat": RetiredOption(1, _DRIVE_WELL),
    "explore_hold_probability": RetiredOption(0.0, _DRIVE_WELL),
    "terminal_fraction": RetiredOption(0.0, _DRIVE_WELL),
    "critic_layer_norm": RetiredOption(False, _DRIVE_WELL),
    "warmup_policy": RetiredOption("uniform", _DRIVE_WELL),
    "twin_critics": RetiredOption(False, _DRIVE_WELL),
    "target_noise": RetiredOption(0.0, _DRIVE_WELL),
    "target_noise_clip": RetiredOption(0.5, _DRIVE_WELL),
    "policy_delay": RetiredOption(1, _DRIVE_WELL),
    "replay": RetiredOption("uniform", _LEVERS),
    "lap_alpha": RetiredOption(0.4, _LEVERS),
    "lap_min_priority": RetiredOption(1.0, _LEVERS),
    "guide_residual": RetiredOption(False, _LEVERS),
    "preactivation_l2": RetiredOption(0.0, None, _UNMEASURED_COMMIT),
    "guide_decay_steps": RetiredOption(0, None, _UNMEASURED_COMMIT),
    "guide_filter_margin": RetiredOption(0.0, None, _UNMEASURED_COMMIT),
    "guide_filter": RetiredOption("none", _LEVERS, _THIRD_COMMIT, ("guide_weight", 0)),
    "gradient_steps": RetiredOption(1, _LEVERS, _THIRD_COMMIT),
    "random_warmup": RetiredOption(True, None, _THIRD_COMMIT),
    "average_multiplier": RetiredOption(False, _BUDGET, _BUDGET_COMMIT),
    "budget_noise_free_every": RetiredOption(0, _KEEPABLE_BUDGET, _KEEPABLE_BUDGET_COMMIT),
}
"""Each retired key, with its off value and its study."""


class RetiredOptionError(ValueError):
    """A config or checkpoint uses an option that frl no longer has."""


def retired_message(key: str, value: Any) -> str:
    """The one line that refuses ``key=value``."""
    option = RETIRED_OPTIONS[key]
    why = (
        "no study measured it and no preset used it"
        if option.study is None
        else f"docs/studies.md, {option.study}, measured it as not helping"
    )
    return (
        f"agent.{key}={value!r} was retired: {why}, and commit {option.commit} removed it; "
        f"only {option.off!r} (off) still loads"
    )


def is_off(key: str, value: Any) -> bool:
    """Whether ``value`` is the retired ``key``'s off value (``1`` and ``1.0`` alike)."""
    off = RETIRED_OPTIONS[key].off
    if isinstance(off, bool) or isinstance(value, bool):
        return isinstance(value, bool) and isinstance(off, bool) and value == off
    return value == off


def without_retired(options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` less the retired keys set to their off values.

    Raises:
        RetiredOptionError: a retired key at any other value (the first such key).
    """
    kept = {}
    for key, value in options.items():
        if key not in RETIRED_OPTIONS:
            kept[key] = value
            continue
        idle_when = RETIRED_OPTIONS[key].idle_when
        idle = idle_when is not None and options.get(idle_when[0], None) == idle_when[1]
        if not idle and not is_off(key, value):
            raise RetiredOptionError(retired_message(key, value))
    return kept
