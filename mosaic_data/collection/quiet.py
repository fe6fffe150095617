"""Keep the terminal for our own progress bar while LeRobot writes and merges datasets.

LeRobot's writer runs a Hugging Face ``datasets.map`` per saved episode (a "Map: 100%" bar each time), the
AV1 encoder prints its banner for every video, and libav reports every mp4 it finalizes ("Starting second
pass: moving the moov atom ...") at its info level. Errors still come through. The settings are process-wide:
entry points (the CLI's collect and merge, collection workers, benches) call it, library functions do not.
"""

from __future__ import annotations

import os


def quiet_dataset_writing() -> None:
    """Turn off the per-episode ``datasets`` bars, SVT-AV1's banner and libav's info messages in this process."""
    import av
    import datasets

    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 reads it whenever an encoder starts: errors only
    # Not HF_DATASETS_DISABLE_PROGRESS_BARS: LeRobot re-enables the bars after its own quiet sections, which warns
    # on every call when the variable is set.
    datasets.disable_progress_bars()
    # LeRobot puts libav's own terminal logger back after each video (restore_default_callback): set the level
    # that logger prints at, not only PyAV's.
    av.logging.set_libav_level(av.logging.ERROR)
