"""Worker processes a command spawns: the environment variables they inherit, and stopping them."""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager


@contextmanager
def scoped_environment(force: Mapping[str, str] = {}, default: Mapping[str, str] = {}) -> Iterator[None]:  # noqa: B006
    """Set ``force`` always and ``default`` where unset (spawned children inherit them); restore on exit."""
    saved = {name: os.environ.get(name) for name in (*force, *default)}
    os.environ.update(force)
    for name, value in default.items():
        os.environ.setdefault(name, value)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def stop_processes(processes, timeout_s: float = 30) -> None:
    """Terminate the workers still running (Ctrl-C, an error, a dead sibling) and reap every one, so no child
    outlives the command that started it."""
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout=timeout_s)
