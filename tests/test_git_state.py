"""git_state: the commit a run trained at, and whether the code it ran differs from it."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from frl.provenance import git_state

pytestmark = pytest.mark.skipif(shutil.which("git") is None, reason="needs git")


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-c", "user.name=t", "-c", "user.email=t@t", *args],
        cwd=repo,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()


@pytest.fixture()
def checkout(tmp_path: Path) -> Path:
    repo = tmp_path / "checkout"
    for name in ("frl/train.py", "frl/conf/config.yaml", "docs/results.md", "pyproject.toml"):
        (repo / name).parent.mkdir(parents=True, exist_ok=True)
        (repo / name).write_text("x\n")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    _git(repo, "commit", "-q", "-m", "init")
    return repo


def test_clean_checkout_reports_its_commit(checkout: Path) -> None:
    assert git_state(checkout / "frl") == (_git(checkout, "rev-parse", "HEAD"), False)


def test_results_written_into_docs_do_not_make_a_run_dirty(checkout: Path) -> None:
    (checkout / "docs/results.md").write_text("rebuilt\n")
    (checkout / "docs/new-run.json").write_text("{}\n")
    assert git_state(checkout / "frl")[1] is False


@pytest.mark.parametrize(
    "change", ["frl/train.py", "frl/conf/config.yaml", "pyproject.toml", "frl/new_module.py"]
)
def test_changed_or_new_code_makes_a_run_dirty(checkout: Path, change: str) -> None:
    (checkout / change).write_text("changed\n")
    assert git_state(checkout / "frl")[1] is True


def test_a_package_outside_any_checkout_has_no_git_state(tmp_path: Path) -> None:
    (tmp_path / "frl").mkdir()
    assert git_state(tmp_path / "frl") == (None, None)


def test_a_package_inside_someone_elses_repository_has_no_git_state(checkout: Path) -> None:
    # An installed frl in a venv that happens to sit inside another project's repository.
    installed = checkout / ".venv/lib/site-packages/frl"
    installed.mkdir(parents=True)
    assert git_state(installed) == (None, None)
