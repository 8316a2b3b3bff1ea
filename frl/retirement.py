"""Options that frl retired: measured by a study and found not to help, or never measured
and used by no preset.

A config or checkpoint may still name one at the value that switched it off: it loads
as if the key were absent, so every run and checkpoint made before the retirement still
reads. Any other value is refused in one line that names the key, the study that measured
it (a section of docs/studies.md) and the commit that retired it, where the code is still
there to read. Each config group keeps its own table (:mod:`frl.agents.retired`,
:data:`frl.envs.config.RETIRED_ENV_OPTIONS`, :data:`frl.envs.config.RETIRED_REWARD_OPTIONS`,
:data:`frl.federation.run_settings.RETIRED_FEDERATION_OPTIONS`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class RetiredOption:
    off: Any
    """The value that left the run as it is without the option."""
    study: str | None
    """Where docs/studies.md gives what it measured; None: no study measured it."""
    commit: str
    """The commit that removed it."""
    idle_when: tuple[str, Any] | None = None
    """``(key, value)``: where the same options set ``key`` to ``value`` the option did
    nothing at any value (a Q-filter with no imitation term to filter), so it loads."""


class RetiredOptionError(ValueError):
    """A config or checkpoint uses an option that frl no longer has."""


def retired_message(group: str, key: str, option: RetiredOption, value: Any) -> str:
    """The one line that refuses ``group.key=value``."""
    why = (
        "no study measured it and no preset used it"
        if option.study is None
        else f"docs/studies.md, {option.study}, measured it as not helping"
    )
    return (
        f"{group}.{key}={value!r} was retired: {why}, and commit {option.commit} removed it; "
        f"only {option.off!r} (off) still loads"
    )


def is_off(option: RetiredOption, value: Any) -> bool:
    """Whether ``value`` is ``option``'s off value (``1`` and ``1.0`` alike)."""
    off = option.off
    if isinstance(off, bool) or isinstance(value, bool):
        return isinstance(value, bool) and isinstance(off, bool) and value == off
    return value == off


def without_retired(
    options: Mapping[str, Any], retired: Mapping[str, RetiredOption], group: str
) -> dict[str, Any]:
    """``options`` of config ``group`` less the ``retired`` keys set to their off values.

    Raises:
        RetiredOptionError: a retired key at any other value (the first such key).
    """
    kept = {}
    for key, value in options.items():
        if key not in retired:
            kept[key] = value
            continue
        idle_when = retired[key].idle_when
        idle = idle_when is not None and options.get(idle_when[0], None) == idle_when[1]
        if not idle and not is_off(retired[key], value):
            raise RetiredOptionError(retired_message(group, key, retired[key], value))
    return kept
