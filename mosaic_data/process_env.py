"""Environment variables set for the worker processes a command spawns, and restored afterwards."""

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
