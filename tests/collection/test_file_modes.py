"""Datasets are as readable as the user's umask says: every file mode 0666 and every folder 0777 less the umask.

LeRobot's aggregation writes videos through ``tempfile`` (mode 0600), so a collection of several shards and every
merge would otherwise hold videos only their owner can read, beside metadata everyone can.
"""

from __future__ import annotations

import io
import os
import stat
from contextlib import redirect_stdout
from pathlib import Path

UMASK = 0o022


def _modes_not_following_the_umask(root: Path) -> list[str]:
    """``path: mode`` of every entry under ``root`` (itself included) whose mode is not what ``UMASK`` gives."""
    wrong = []
    for path in [root, *sorted(root.rglob("*"))]:
        expected = (0o777 if path.is_dir() else 0o666) & ~UMASK
        mode = stat.S_IMODE(path.lstat().st_mode)
        if mode != expected:
            wrong.append(f"{path.relative_to(root.parent)}: {mode:o}")
    return wrong


def _collect(cli, output: Path, variations: str) -> Path:
    with redirect_stdout(io.StringIO()):
        status = cli("collect", "--task", "door", "--robot", "panda", "--variations", variations, "--episodes", "1",
                     "--workers", "1", "--image-size", "48x88", "--quiet", "--output-dir", str(output))
    assert status == 0
    return output / "mosaic" / "door_panda"


def test_a_collection_of_two_shards_and_a_merge_follow_the_umask(tmp_path, cli):
    previous = os.umask(UMASK)
    try:
        two_shards = _collect(cli, tmp_path / "two", "0,1")  # one shard per variation: LeRobot aggregates them
        one_shard = _collect(cli, tmp_path / "one", "2")
        with redirect_stdout(io.StringIO()):
            status = cli("merge", str(two_shards), str(one_shard), "--repo-id", "mosaic/merged",
                         "--output-dir", str(tmp_path / "merged"))
        assert status == 0
    finally:
        os.umask(previous)
    merged = tmp_path / "merged" / "mosaic" / "merged"
    assert list(merged.rglob("*.mp4")), "the merge wrote videos"
    for root in (two_shards, one_shard, merged):
        assert _modes_not_following_the_umask(root) == []
