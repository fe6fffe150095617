"""Output files of recordings (``.mp4`` videos, rerun ``.rrd`` files): checked before the work, written whole.

A command that records for minutes (expert rollouts, an evaluation) checks its output path first, so a typo
costs a one-line error instead of the run; the file itself is written to a temporary beside the target and
renamed over it only when complete, so a failure never leaves a 0-byte or half-written file behind. Images go
into rerun recordings as JPEG: raw RGB frames made recordings tens of megabytes per episode.
"""

from __future__ import annotations

import io
import os
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mosaic_data.atomic_files import plain_file_mode

JPEG_QUALITY = 80
"""JPEG quality of camera frames in recordings: a small fraction of a raw frame's bytes, hard to tell apart."""


def check_output_file(path: Path, suffix: str, option: str, example: str) -> None:
    """Raise a one-line ValueError unless ``path`` can become a new ``suffix`` file (missing folders are made later).

    ``option`` names the flag in messages; ``example`` is a file name suggested when ``path`` is a folder.
    """
    if path.is_dir():
        raise ValueError(f"{option} {path} is a folder: give a file in it, e.g. {option} {path / example}")
    if path.suffix.lower() != suffix:
        raise ValueError(f"{option} must name a {suffix} file, got {str(path)!r}: e.g. {option} {path.with_suffix(suffix)}")
    check_folder_takes_file(path, option)


def check_folder_takes_file(path: Path, option: str) -> None:
    """Raise a one-line ValueError unless a file can be created at ``path`` (its missing folders are made later).

    The nearest existing folder above it must be a folder, and writable: probed with a real file, since root
    passes every permission check and a read-only file system answers only to a write.
    """
    existing = path.absolute().parent
    while not existing.exists():  # the folders that will be made; the first one that exists must take them
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"cannot write {path}: {existing} is a file, not a folder: choose another {option}")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as error:
        raise ValueError(f"cannot write {path}: {existing} is not writable ({error.strerror}): choose another {option}") from None


@contextmanager
def file_written_whole(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix, so writers pick the same format) that replaces
    ``path`` when the block finishes; on any error it is removed and ``path`` is left as it was."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix)
    os.close(handle)
    temporary = Path(name)
    try:
        yield temporary
        os.chmod(temporary, plain_file_mode())  # mkstemp makes 0600: give the mode a plain open() would
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


@contextmanager
def rerun_file(path: Path, application_id: str, blueprint, recording_id: str | None = None):
    """A rerun RecordingStream saving to ``path`` with ``blueprint`` as its default; the file appears whole
    when the block finishes, and not at all if it fails."""
    import rerun as rr

    with file_written_whole(path) as temporary:
        stream = rr.RecordingStream(application_id, recording_id=recording_id)
        stream.save(str(temporary), default_blueprint=blueprint)
        try:
            yield stream
            stream.flush()
        finally:
            stream.disconnect()  # closes the file before it is renamed (or removed)


def jpeg_bytes(image: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    """(H, W, 3) uint8 RGB -> JPEG file content, for ``rr.EncodedImage``."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="JPEG", quality=quality)
    return buffer.getvalue()


def send_jpegs(stream, entity: str, frames: Sequence[np.ndarray], indexes: list) -> None:
    """Log ``frames`` (RGB uint8) at ``indexes`` as one column of JPEG images."""
    import rerun as rr

    blobs = [jpeg_bytes(frame) for frame in frames]
    stream.send_columns(entity, indexes=indexes, columns=rr.EncodedImage.columns(blob=blobs, media_type=["image/jpeg"] * len(blobs)))


@dataclass(frozen=True)
class StepTimelines:
    """The timelines of a recording of episodes played one after the other: ``episode`` (its number), a running
    step count over all of them (``counter``), the step within the episode (``step``) and ``time`` at ``fps`` in
    exact nanoseconds, so the viewer's default timeline plays in real time."""

    fps: int
    counter: str
    step: str = "step"

    def _time(self, global_steps):
        return (np.asarray(global_steps) * (10**9 // self.fps)).astype("timedelta64[ns]")  # exact, not float

    def columns(self, episode: int, first: int, count: int) -> list:
        """Index columns of ``count`` steps of ``episode`` whose first one is global step ``first``."""
        import rerun as rr

        steps = np.arange(count)
        return [
            rr.TimeColumn("episode", sequence=np.full(count, episode)),
            rr.TimeColumn(self.counter, sequence=first + steps),
            rr.TimeColumn(self.step, sequence=steps),
            rr.TimeColumn("time", duration=self._time(first + steps)),
        ]

    def set(self, stream, episode: int, first: int, step: int) -> None:
        """Row-wise logging at ``step`` of ``episode`` (whose first step is global step ``first``)."""
        stream.set_time("episode", sequence=episode)
        stream.set_time(self.counter, sequence=first + step)
        stream.set_time(self.step, sequence=step)
        stream.set_time("time", duration=self._time(first + step))
