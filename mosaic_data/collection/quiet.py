"""Keep the terminal for our own progress bar while LeRobot writes and merges datasets.

LeRobot's writer runs a Hugging Face ``datasets.map`` per saved episode (a "Map: 100%" bar each time), the
AV1 encoder prints its banner for every video, libav reports every mp4 it finalizes ("Starting second
pass: moving the moov atom ...") at its info level, and LeRobot's aggregation (every merge: the shards of a
collection, ``mosaic-data merge``) draws two bars of its own ("Validate all meta data", "Copy data and
videos") that break through ours. Errors still come through. The settings are process-wide: entry points
(the CLI's collect and merge, collection workers, benches) call it, library functions do not.
"""

from __future__ import annotations

import functools
import os
import threading
import types
from typing import Any


def quiet_dataset_writing() -> None:
    """Turn off the per-episode ``datasets`` bars, LeRobot's aggregation bars, SVT-AV1's banner and libav's
    info messages in this process, and keep tqdm from creating a cross-process lock."""
    import av
    import datasets

    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 reads it whenever an encoder starts: errors only
    # Not HF_DATASETS_DISABLE_PROGRESS_BARS: LeRobot re-enables the bars after its own quiet sections, which warns
    # on every call when the variable is set.
    datasets.disable_progress_bars()
    # LeRobot puts libav's own terminal logger back after each video (restore_default_callback): set the level
    # that logger prints at, not only PyAV's.
    av.logging.set_libav_level(av.logging.ERROR)
    thread_only_progress_lock()
    quiet_lerobot_aggregation()


def thread_only_progress_lock() -> None:
    """Give tqdm a lock for this process's threads only, before its first bar.

    By default the first tqdm bar of a process (even a disabled one: ``datasets`` opens one per saved episode)
    creates a ``multiprocessing.RLock``, a named semaphore registered with the resource tracker and released
    only by the process's exit handlers. A collection worker stopped by the parent (Ctrl-C, or still exiting
    when the collection ends) never runs them, and the tracker then warns "There appear to be 1 leaked
    semaphore objects to clean up at shutdown". Our bars are drawn by one process, so a thread lock is enough.
    """
    import tqdm

    tqdm.tqdm.set_lock(threading.RLock())


class _SilentTqdmModule(types.ModuleType):
    """Stands in for the ``tqdm`` module inside one library module: its ``tqdm.tqdm`` bars are disabled."""

    def __init__(self, real: types.ModuleType) -> None:
        super().__init__(real.__name__, real.__doc__)
        self._real = real
        self.tqdm = functools.partial(real.tqdm, disable=True)

    def __getattr__(self, name: str) -> Any:  # everything else is the real module's
        return getattr(self._real, name)


def quiet_lerobot_aggregation() -> None:
    """Disable the progress bars of ``lerobot.datasets.aggregate`` (it calls ``tqdm.tqdm(...)`` with no way to
    turn them off) by giving that module a ``tqdm`` whose bars are disabled; idempotent."""
    from lerobot.datasets import aggregate

    if not isinstance(aggregate.tqdm, _SilentTqdmModule):
        aggregate.tqdm = _SilentTqdmModule(aggregate.tqdm)
