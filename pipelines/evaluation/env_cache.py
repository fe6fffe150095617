"""A few live environments per worker: building a scene costs seconds, keeping all 61 x 2 costs gigabytes."""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any


class EnvCache:
    """At most ``size`` environments; the least recently used one is closed to make room."""

    def __init__(self, size: int = 4) -> None:
        self.size = size
        self._envs: OrderedDict[Hashable, Any] = OrderedDict()

    def get(self, key: Hashable, build: Callable[[], Any]) -> Any:
        if key in self._envs:
            self._envs.move_to_end(key)
            return self._envs[key]
        if len(self._envs) >= self.size:
            _, oldest = self._envs.popitem(last=False)
            oldest.close()
        self._envs[key] = env = build()
        return env

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()
