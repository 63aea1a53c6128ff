"""gaintune.files: atomic writes that never follow a planted symlink; bounded reads of regular files only."""

from __future__ import annotations

import os

import pytest

from gaintune.errors import SpecError
from gaintune.files import read_bytes_bounded, read_text_bounded, write_atomic


def test_write_atomic_replaces_a_planted_symlink_without_touching_its_target(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("precious")
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "result.json").symlink_to(outside)
    write_atomic(folder / "result.json", "{}")
    assert outside.read_text() == "precious"
    assert not (folder / "result.json").is_symlink()
    assert (folder / "result.json").read_text() == "{}"
    assert [p.name for p in folder.iterdir()] == ["result.json"]  # no temporary file left behind


def test_write_atomic_leaves_no_temporary_file_on_failure(tmp_path):
    (tmp_path / "d").mkdir()  # a folder at the destination: the rename fails
    with pytest.raises(OSError):
        write_atomic(tmp_path / "d", b"x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_read_of_dev_zero_is_refused_naming_a_regular_file():
    with pytest.raises(SpecError, match="not a regular file"):
        read_bytes_bounded("/dev/zero", "spec")


def test_read_of_a_fifo_is_refused_without_hanging(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(SpecError, match="not a regular file"):
        read_bytes_bounded(fifo, "spec")


def test_read_over_the_cap_names_the_limit(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_bytes(b"a" * 101)
    with pytest.raises(SpecError, match="limit is 100 bytes") as err:
        read_bytes_bounded(big, "spec", limit=100)
    assert err.value.field == "spec"
    assert read_bytes_bounded(big, "spec", limit=101) == b"a" * 101


def test_read_text_of_binary_is_a_spec_error(tmp_path):
    p = tmp_path / "bin"
    p.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(SpecError, match="not UTF-8"):
        read_text_bounded(p, "gains")


def test_a_folder_where_a_file_goes_is_named_as_one(tmp_path):
    """Regression: a folder in a file's place (a tuner's policy.npz, a spec) gave "[Errno 21] Is a directory: 3"
    (os.fdopen refused the folder's descriptor before the file-type check), and leaked the descriptor."""
    (tmp_path / "policy.npz").mkdir()
    with pytest.raises(SpecError) as e:
        read_bytes_bounded(tmp_path / "policy.npz", "tuner")
    assert e.value.field == "tuner" and "is not a regular file" in e.value.message
