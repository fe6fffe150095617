"""Keep the terminal for our own progress bar while LeRobot writes and merges datasets.

LeRobot's writer runs a Hugging Face ``datasets.map`` per saved episode (a "Map: 100%" bar each time), and
libav reports every mp4 it finalizes ("Starting second pass: moving the moov atom ...") at its info level.
Errors still come through.
"""

from __future__ import annotations


def quiet_dataset_writing() -> None:
    """Turn off the per-episode ``datasets`` bars and libav's info messages in this process."""
    import av
    import datasets

    datasets.disable_progress_bars()
    # LeRobot puts libav's own terminal logger back after each video (restore_default_callback): set the level
    # that logger prints at, not only PyAV's.
    av.logging.set_libav_level(av.logging.ERROR)
