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
