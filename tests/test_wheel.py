"""The built wheel trains from outside the checkout: configs ship inside the package.

Builds frl's wheel, installs it (without dependencies) into a fresh virtual environment
that borrows this environment's installed dependencies through a ``.pth`` file, then
runs ``python -m frl.train --help`` and a tiny training run from an empty directory, so
that nothing of the checkout is on the path.
"""

from __future__ import annotations

import json
import os
import site
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TINY_RUN = [
    "federation=central",
    "budget=paper",  # an update every step: rounds of 20 updates are 20 steps
    "total_steps=40",
    "interval=20",
    "eval_episodes=1",
    "yardsticks=[full_throttle]",
    "agent.hidden_sizes=[8]",
    "agent.learning_starts=10",
    "agent.batch_size=8",
    "agent.buffer_size=100",
    "progress=false",
]

# One xdist worker runs this module: its tests share one installed wheel (a module fixture).
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("wheel")]


def _run(command: list[str], cwd: Path, env: dict[str, str], timeout: float = 300) -> str:
    result = subprocess.run(
        command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False
    )
    assert result.returncode == 0, f"{command}\n{result.stdout[-2000:]}\n{result.stderr[-4000:]}"
    return result.stdout + result.stderr


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The ``python`` of a fresh venv holding frl's wheel."""
    work = tmp_path_factory.mktemp("wheel")
    env = {**os.environ, "PIP_NO_INDEX": "1", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
         "-w", str(work / "dist"), str(ROOT)],
        cwd=work, env=env,
    )  # fmt: skip
    (wheel,) = (work / "dist").glob("frl-*.whl")
    venv.create(work / "venv", with_pip=False)
    python = work / "venv" / "bin" / "python"
    purelib = _run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        cwd=work, env=env,
    ).strip()  # fmt: skip
    borrowed = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    borrowed |= set(site.getsitepackages())
    (Path(purelib) / "borrowed-deps.pth").write_text("\n".join(sorted(borrowed)) + "\n")
    _run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--target", purelib, str(wheel)],
        cwd=work, env=env,
    )  # fmt: skip
    return python


def _outside_env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    return env


def test_the_wheel_carries_the_configs_and_help_works(installed: Path, tmp_path: Path):
    where = _run(
        [str(installed), "-c", "import frl, frl.conf; print(frl.__file__)"],
        cwd=tmp_path, env=_outside_env(),
    )  # fmt: skip
    assert not where.strip().startswith(str(ROOT / "frl"))  # the wheel's frl, not the checkout's
    out = _run([str(installed), "-m", "frl.train", "--help"], cwd=tmp_path, env=_outside_env())
    assert "traffic: dense, paper" in out and "federation: central, fedavg, separate" in out


def test_a_tiny_run_trains_from_the_installed_wheel(installed: Path, tmp_path: Path):
    run_dir = tmp_path / "run"
    _run(
        [str(installed), "-m", "frl.train", *TINY_RUN, f"run_dir={run_dir}"],
        cwd=tmp_path, env=_outside_env(),
    )  # fmt: skip
    results = json.loads((run_dir / "results.json").read_text())
    assert results["training"]["steps_per_client"] == 40
    assert results["evaluation"]["episodes_per_task"] == 1
    assert results["versions"]["git_commit"] is None  # not a checkout: no git state claimed
