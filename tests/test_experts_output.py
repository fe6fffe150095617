"""`mosaic-data experts --video/--rerun`: the output path is checked before any rollout, the episode count is
bounded, and a failed write leaves no file behind."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from mosaic_data.cli import main  # noqa: E402
from mosaic_data.rollout import Episode, write_rerun, write_video  # noqa: E402

ONE_ROLLOUT = ["experts", "--task", "door", "--robot", "panda", "--episodes", "1", "--variations", "0"]


@pytest.mark.parametrize(
    "option, make_path, message",
    [
        ("--video", lambda tmp: tmp, "is a folder: give a file in it, e.g. --video {tmp}/door.mp4"),
        ("--rerun", lambda tmp: tmp, "is a folder: give a file in it, e.g. --rerun {tmp}/door.rrd"),
        ("--video", lambda tmp: tmp / "door.rrd", "--video must name a .mp4 file"),
        ("--rerun", lambda tmp: tmp / "door.mp4", "--rerun must name a .rrd file"),
        ("--video", lambda tmp: tmp / "notes.txt" / "door.mp4", "notes.txt is a file, not a folder"),
        ("--rerun", lambda tmp: tmp / "notes.txt" / "deeper" / "door.rrd", "notes.txt is a file, not a folder"),
    ],
    ids=["video-folder", "rerun-folder", "video-suffix", "rerun-suffix", "video-under-file", "rerun-under-file"],
)
def test_bad_output_path_fails_in_one_line_before_any_rollout(tmp_path, capsys, option, make_path, message):
    (tmp_path / "notes.txt").write_text("not a folder")
    assert main([*ONE_ROLLOUT, option, str(make_path(tmp_path))]) == 2
    captured = capsys.readouterr()
    assert "success" not in captured.out, "no rollout may run before the path is checked"
    (line,) = captured.err.strip().splitlines()
    assert message.format(tmp=tmp_path) in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"], "no file, not even an empty one"


def test_unwritable_output_folder_fails_before_any_rollout(capsys):
    # /proc takes no new files, even for root (a chmod'ed folder would not stop root)
    assert main([*ONE_ROLLOUT, "--video", "/proc/mosaic_door.mp4"]) == 2
    captured = capsys.readouterr()
    assert "success" not in captured.out
    (line,) = captured.err.strip().splitlines()
    assert "cannot write /proc/mosaic_door.mp4" in line and "not writable" in line


def test_episode_count_is_bounded(capsys):
    # Refused up front, not after building (and rolling out) a list of 10^9 seeds.
    try:
        status = main(["experts", "--task", "door", "--episodes", "1000000000"])
    except SystemExit as exit_request:  # argparse's refusal, whether or not main turns it into a status
        status = exit_request.code
    assert status == 2
    (line,) = [line for line in capsys.readouterr().err.splitlines() if "error:" in line]
    assert "--episodes" in line and "from 1 to 10000" in line


def _episodes(height: int, width: int, steps: int = 3) -> list[Episode]:
    episode = Episode("door", "panda", 0, 0, "push the left door open", success=True, length=steps)
    episode.frames = [np.full((height, width, 3), 40 * k, np.uint8) for k in range(steps + 1)]
    episode.actions = [np.zeros(7) for _ in range(steps)]
    episode.states = [np.zeros(10) for _ in range(steps)]
    return [episode]


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # imageio's writer, closed by GC
def test_a_video_that_cannot_be_encoded_leaves_no_file(tmp_path):
    # H.264 cannot encode odd frame sizes: the encoder fails after the file was opened, and no 0-byte mp4 is left.
    with pytest.raises(Exception):
        write_video(tmp_path / "door.mp4", _episodes(101, 181))
    assert list(tmp_path.iterdir()) == []


def test_a_failed_recording_leaves_no_file_and_keeps_an_old_one(tmp_path):
    target = tmp_path / "door.rrd"
    write_rerun(target, _episodes(48, 88))
    old = target.read_bytes()
    broken = _episodes(48, 88)
    broken[0].actions[1] = None  # not an action: fails half way through logging
    with pytest.raises(Exception):
        write_rerun(target, broken)
    assert target.read_bytes() == old
    assert [p.name for p in tmp_path.iterdir()] == ["door.rrd"], "no temporary left behind"
