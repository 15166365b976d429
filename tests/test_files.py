"""proto_brax.files.atomic_write: all or nothing, and the file mode a plain open() gives."""

from __future__ import annotations

import os

import pytest

from proto_brax.files import atomic_write, copy_atomic, write_text_atomic


def test_failure_keeps_the_previous_file_and_leaves_no_temp(tmp_path):
    path = tmp_path / "sub" / "r.json"
    write_text_atomic(path, "old")  # creates the parent directory
    with pytest.raises(RuntimeError, match="boom"), atomic_write(path) as f:
        f.write("half of the new")
        raise RuntimeError("boom")
    assert path.read_text() == "old" and os.listdir(path.parent) == ["r.json"]


def test_mode_follows_the_umask_as_open_does(tmp_path):
    old = os.umask(0o027)
    try:
        write_text_atomic(tmp_path / "a", "x")
        with open(tmp_path / "b", "w") as f:
            f.write("x")
    finally:
        os.umask(old)
    assert (tmp_path / "a").stat().st_mode & 0o777 == (tmp_path / "b").stat().st_mode & 0o777 == 0o640


def test_copy_and_bad_mode(tmp_path):
    (tmp_path / "src.bin").write_bytes(b"\x00\x01png")
    copy_atomic(tmp_path / "src.bin", tmp_path / "out" / "dst.bin")
    assert (tmp_path / "out" / "dst.bin").read_bytes() == b"\x00\x01png"
    with pytest.raises(ValueError, match="mode 'w' or 'wb'"), atomic_write(tmp_path / "c", "a"):
        pass
