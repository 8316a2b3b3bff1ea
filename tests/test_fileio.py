"""Atomic writes: all or nothing, no temporary files left, ordinary permissions."""

import os
import stat

import pytest

from frl.fileio import atomic_write, read_json, write_json_atomic


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path) -> None:
    path = tmp_path / "results.json"
    write_json_atomic(path, {"round": 1})
    with pytest.raises(RuntimeError), atomic_write(path) as f:
        f.write(b'{"round": ')
        raise RuntimeError("killed mid-write")
    assert read_json(path) == {"round": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_files_get_the_permissions_of_a_plain_open(tmp_path) -> None:
    previous = os.umask(0o022)
    try:
        write_json_atomic(tmp_path / "a.json", [1])
        os.umask(0o077)
        write_json_atomic(tmp_path / "b.json", [2])
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / "a.json").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "b.json").stat().st_mode) == 0o600


def test_parent_directories_are_created(tmp_path) -> None:
    path = tmp_path / "run" / "models" / "x.bin"
    with atomic_write(path) as f:
        f.write(b"abc")
    assert path.read_bytes() == b"abc"
