"""The one atomic writer behind the sidecar, the shard records, the reports and the mesh and fixture caches."""

import os
import stat

import pytest

from mosaic_data.atomic_files import write_bytes_atomically


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
