"""Writing a file so that a reader, a parallel writer or a crash never sees half of it.

Used for the collection's sidecar and shard records, the evaluation reports and the shared mesh cache,
which parallel workers may fill at the same moment: each writer writes its own temporary file beside the
target and renames it over the target (atomic on POSIX), and a failed write leaves no temporary behind.
``mkstemp`` creates the temporary with mode 0600; it gets the mode a plain ``open`` would give (0666 less the
umask) before the rename, so a shared dataset, report or cache stays as readable as the user's umask intends.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def plain_file_mode() -> int:
    """The mode ``open()`` gives a new file: 0666 less the umask (``mkstemp`` temporaries get 0600)."""
    mask = os.umask(0)  # the only portable way to read it: set and restore at once
    os.umask(mask)
    return 0o666 & ~mask


def write_bytes_atomically(path: Path, content: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(content)
        os.chmod(temporary, plain_file_mode())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
