"""The one atomic writer behind the sidecar, the shard records, the reports and the mesh and fixture caches."""

import os
import stat
import tempfile
from pathlib import Path

import pytest

from mosaic_data.atomic_files import current_umask, give_plain_modes, write_bytes_atomically


def test_writes_the_content_and_makes_the_folder(tmp_path):
    target = tmp_path / "deep" / "file.json"
    write_bytes_atomically(target, b"{}\n")
    assert target.read_bytes() == b"{}\n"
    assert sorted(p.name for p in target.parent.iterdir()) == ["file.json"]


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "file.json"
    write_bytes_atomically(target, b"old")
    with pytest.raises(TypeError):
        write_bytes_atomically(target, "not bytes")  # type: ignore[arg-type]
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.json"]


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_the_written_file_follows_the_umask_like_a_plain_open(tmp_path, umask, mode):
    previous = os.umask(umask)
    try:
        write_bytes_atomically(tmp_path / "shared.json", b"{}")
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / "shared.json").stat().st_mode) == mode


def test_the_umask_is_read_without_being_changed():
    previous = os.umask(0o027)
    try:
        assert current_umask() == 0o027
        assert current_umask() == 0o027
    finally:
        os.umask(previous)


def test_a_tree_written_through_temporaries_gets_the_modes_of_plain_open_and_mkdir(tmp_path):
    previous = os.umask(0o022)
    try:
        folder = Path(tempfile.mkdtemp(dir=tmp_path))  # 0700
        handle, video = tempfile.mkstemp(dir=folder, suffix=".mp4")  # 0600
        os.close(handle)
        (tmp_path / "link").symlink_to(video)
        give_plain_modes(tmp_path)
    finally:
        os.umask(previous)
    assert stat.S_IMODE(tmp_path.stat().st_mode) == 0o755
    assert stat.S_IMODE(folder.stat().st_mode) == 0o755
    assert stat.S_IMODE(os.stat(video).st_mode) == 0o644
