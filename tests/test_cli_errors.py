"""A user's mistake on the command line: one line on stderr, exit code 2, no traceback.

Most cases call the entry points in this process (fast); one per command runs
``python -m`` for real.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf
from train_helpers import compose_config

from frl import evaluate, train
from frl.fileio import write_json_atomic


@pytest.fixture
def run_cli(monkeypatch, capsys):
    """``run_cli(module, *args, cwd=...)``: the command's exit code, stdout and stderr."""

    def run(module: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
        monkeypatch.chdir(cwd)
        monkeypatch.setattr(sys, "argv", [module, *args])
        try:
            code = evaluate.main(list(args)) if module == "frl.evaluate" else train.main()
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 1
        out = capsys.readouterr()
        return subprocess.CompletedProcess([module, *args], code or 0, out.out, out.err)

    return run


def run_for_real(module: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def assert_one_line_error(result: subprocess.CompletedProcess[str], prefix: str, text: str):
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(prefix) and text in lines[0], lines[0]
    assert "Traceback" not in result.stderr + result.stdout


@pytest.mark.parametrize(
    ("override", "text"),
    [
        ("interval=abc", "could not be converted to Integer"),
        ("agent.lrr=1", "Key 'lrr' not in 'AgentSchema'"),
        ("federation=bogus", "federation/bogus"),
        ("nonsense", "Error parsing override 'nonsense'"),
        ("eval_episodes=-1", "eval_episodes must be a non-negative integer"),
    ],
)
def test_a_bad_override_to_frl_train(run_cli, override, text, tmp_path):
    result = run_cli("frl.train", override, f"run_dir={tmp_path / 'run'}", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", text)
    assert not (tmp_path / "run").exists()


def test_python_m_frl_train_with_a_bad_override(tmp_path):
    result = run_for_real("frl.train", "interval=abc", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", "could not be converted to Integer")


def test_a_bad_value_in_a_sweep_is_found_before_any_job(run_cli, tmp_path):
    result = run_cli("frl.train", "-m", "seed=0,x", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", "seed=x")
    assert not (tmp_path / "multirun").exists()


def test_resuming_a_directory_with_no_run(run_cli, tmp_path):
    result = run_cli("frl.train", f"resume={tmp_path}", cwd=tmp_path)
    assert_one_line_error(result, "frl.train: config error:", "no checkpointed run there")


@pytest.fixture
def finished_looking_run(tmp_path: Path) -> Path:
    """A run directory with a valid config and a model index, but no real models."""
    run_dir = tmp_path / "run"
    (run_dir / "models").mkdir(parents=True)
    OmegaConf.save(compose_config(run_dir), run_dir / "config.yaml")
    write_json_atomic(run_dir / "models" / "index.json", {"left": "global.pt"})
    return run_dir


def test_frl_evaluate_on_a_directory_that_is_no_run(run_cli, tmp_path):
    result = run_cli("frl.evaluate", str(tmp_path), cwd=tmp_path)
    assert_one_line_error(result, "frl.evaluate: error:", "is not an frl run directory")


def test_frl_evaluate_with_a_missing_model(run_cli, finished_looking_run):
    result = run_cli("frl.evaluate", str(finished_looking_run), cwd=finished_looking_run)
    assert_one_line_error(result, "frl.evaluate: error:", "no such file")


def test_frl_evaluate_with_a_corrupt_model(finished_looking_run):
    (finished_looking_run / "models" / "global.pt").write_bytes(b"PK\x03\x04 not a checkpoint")
    result = run_for_real("frl.evaluate", str(finished_looking_run), cwd=finished_looking_run)
    assert_one_line_error(result, "frl.evaluate: error:", "is not a readable checkpoint")


def test_frl_evaluate_with_a_corrupt_config(run_cli, finished_looking_run):
    (finished_looking_run / "config.yaml").write_text("seed: [\n")
    result = run_cli("frl.evaluate", str(finished_looking_run), cwd=finished_looking_run)
    assert_one_line_error(result, "frl.evaluate: error:", "is not a readable config")
