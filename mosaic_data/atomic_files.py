"""Writing a file so that a reader, a parallel writer or a crash never sees half of it.

Used for the collection's sidecar and shard records, the evaluation reports and the shared mesh cache,
which parallel workers may fill at the same moment: each writer writes its own temporary file beside the
target and renames it over the target (atomic on POSIX), and a failed write leaves no temporary behind.
``mkstemp`` creates the temporary with mode 0600; it gets the mode a plain ``open`` would give (0666 less the
umask) before the rename, so a shared dataset, report or cache stays as readable as the user's umask intends.
:func:`give_plain_modes` does the same for a whole folder that another library filled (LeRobot's aggregation
writes its videos through ``tempfile`` too).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any


def current_umask() -> int:
    """The process's umask, read without changing it where Linux shows it in ``/proc/self/status``.

    Elsewhere it is set and restored at once (the only portable way to read it): a file another thread creates in
    that instant would get mode 0666, so the ``/proc`` reading comes first.
    """
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0)
    os.umask(mask)
    return mask


def plain_file_mode() -> int:
    """The mode ``open()`` gives a new file: 0666 less the umask (``mkstemp`` temporaries get 0600)."""
    return 0o666 & ~current_umask()


def give_plain_modes(root: Path) -> None:
    """Give ``root`` and every folder under it the mode ``mkdir`` would (0777 less the umask), and every file the
    mode ``open()`` would (0666 less the umask): what is written under ``root`` is then as readable as the user's
    umask says, whatever temporaries (0600 files, 0700 folders) the writer went through. Links are left alone."""
    mask = current_umask()  # read once for the whole tree
    folder_mode, file_mode = 0o777 & ~mask, 0o666 & ~mask
    os.chmod(root, folder_mode)
    for folder, folders, files in os.walk(root):
        for name in folders:
            path = os.path.join(folder, name)
            if not os.path.islink(path):
                os.chmod(path, folder_mode)
        for name in files:
            path = os.path.join(folder, name)
            if not os.path.islink(path):
                os.chmod(path, file_mode)


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


def json_default(value: Any) -> Any:
    """What ``json.dumps`` writes for a value JSON has no type for: arrays and numpy numbers as lists and
    numbers, sets and tuples as lists, anything else as its ``str``."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (set, tuple)):
        return list(value)
    return str(value)


def write_json_atomically(path: Path, content: dict[str, Any]) -> None:
    """Write ``content`` as indented JSON (see :func:`json_default`) so that a reader (or a crash) never sees half
    a file."""
    write_bytes_atomically(path, (json.dumps(content, indent=2, default=json_default) + "\n").encode())
