"""python -m frl.demo: the gap-acceptance driver's table and an animation of a crossing."""

from PIL import Image

from frl import demo


def test_the_demo_prints_its_table_and_animates_an_arriving_left_turn(tmp_path, capsys):
    gif = tmp_path / "demo.gif"
    demo.main(["--episodes", "3", "--gif", str(gif)])
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines()[2:5]}
    assert set(rows) == {"left", "straight", "right"}
    arrived_left = int(rows["left"][3].split("/")[0])  # task, return, collisions, arrived
    assert arrived_left >= 1  # the driver arrives, so there is a crossing to show
    assert "saved the left turn of seed" in out
    with Image.open(gif) as image:
        assert image.n_frames > 30  # a whole crossing, not a first-step collision


def test_the_demo_drives_a_runs_model_on_its_test_episodes_and_draws_its_collisions(
    tmp_path, capsys, monkeypatch
):
    from train_helpers import compose_config

    from frl.fileio import read_json
    from frl.policies import full_throttle
    from frl.training import train

    run_dir = tmp_path / "run"
    train(compose_config(run_dir, ["eval_episodes=2", "yardsticks=[]"]))
    capsys.readouterr()
    demo.main([str(run_dir), "--gif", str(tmp_path / "model.gif")])
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines()[2:5]}
    tested = read_json(run_dir / "results.json")["evaluation"]["per_task"]
    for task, row in rows.items():  # the table's episodes, driven again: the same outcomes
        assert row[2] == f"{round(tested[task]['collision_rate'] * 2)}/2", task
        assert row[3] == f"{round(tested[task]['arrival_rate'] * 2)}/2", task
    assert (tmp_path / "model.gif").exists()

    # A model that never brakes collides on the first left-turn seed (and the second
    # straight one): each collision is drawn beside the committed rule, one GIF per
    # episode, two pictures wide.
    monkeypatch.setattr(demo, "_model_policy", lambda path, env: full_throttle())
    demo.main([str(run_dir), "--collisions", "--episodes", "2"])
    out = capsys.readouterr().out
    gifs = sorted((run_dir / "collisions").glob("*.gif"))
    assert gifs and f"{len(gifs)} collision(s) drawn" in out
    with Image.open(gifs[0]) as image:
        assert image.width == 2 * image.height


def test_the_demo_refuses_a_directory_that_is_no_run_or_has_no_model(tmp_path, capsys):
    for directory, text in ((tmp_path, "is not a training run"), (tmp_path / "run", "no models/")):
        (tmp_path / "run").mkdir(exist_ok=True)
        if directory != tmp_path:
            (directory / "config.yaml").write_text("seed: 0\n")
        try:
            demo.main([str(directory), "--collisions"])
        except SystemExit as stop:
            assert stop.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and text in err[0], err
        assert not (directory / "collisions").exists()
