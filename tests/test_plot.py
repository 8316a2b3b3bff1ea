"""frl.plot: the picture of a run, of seeds and of settings side by side."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from frl import plot
from frl.report.runs import Episodes, load_run

DATA = Path(__file__).resolve().parents[1] / "docs" / "results" / "data" / "study-data"
DEFAULT = [DATA / "tf8" / f"fedavg-seed{seed}" for seed in (0, 1)]
ROUTE = [DATA / "route" / "tf8" / f"fedavg-seed{seed}" for seed in (0, 1)]


def test_a_vehicles_curve_is_its_last_100_episodes_mean_by_hand() -> None:
    episodes = Episodes(
        end_step=np.array([10, 20, 30]), returns=np.array([1.0, 2.0, 3.0]),
        collision=np.zeros(3), arrived=np.ones(3), steps=np.full(3, 10),
    )  # fmt: skip
    curve = plot.vehicle_curve(episodes, np.array([0, 10, 25, 40]))
    np.testing.assert_allclose(curve, [np.nan, 1.0, 1.5, 2.0])
    many = Episodes(np.arange(1, 151), np.arange(150.0), *(np.zeros(150),) * 3)
    assert plot.vehicle_curve(many, np.array([150]))[0] == np.mean(np.arange(50.0, 150.0))


def test_seeds_of_one_setting_group_and_settings_are_named_by_what_differs() -> None:
    runs = [load_run(path) for path in [*DEFAULT, *ROUTE]]
    settings = plot.settings_of(runs)
    assert [len(s.runs) for s in settings] == [2, 2]
    assert settings[0].label == "env.route_observation=False (seeds 0-1)"
    assert settings[1].label == "env.route_observation=True (seeds 0-1)"
    one = plot.settings_of(runs[:1])
    assert one[0].label == "fedavg-seed0 (seed 0)"


def test_one_run_and_several_settings_draw_a_png(tmp_path: Path) -> None:
    single = plot.draw([load_run(DEFAULT[0])], tmp_path / "one.png")
    several = plot.draw([load_run(p) for p in [*DEFAULT, *ROUTE]], tmp_path / "two.png")
    for path in (single, several):
        assert path.read_bytes().startswith(b"\x89PNG") and path.stat().st_size > 20_000


def test_the_command_writes_the_figure_and_refuses_bad_input_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "seeds.png"
    assert plot.main([*map(str, DEFAULT), "--out", str(out)]) == 0
    assert out.exists() and capsys.readouterr().out.strip() == str(out)
    assert plot.main([str(tmp_path / "nothing")]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("frl.plot:") and "results.json" in error[0]
    assert plot.main([str(DEFAULT[0]), "--out", str(tmp_path / "figure.pdf")]) == 2
    assert "--out must name a .png" in capsys.readouterr().err
    assert not (tmp_path / "figure.pdf").exists()
