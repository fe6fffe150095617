"""The sidecar ``meta/mosaic.json``: everything LeRobot's own metadata does not say about a MOSAIC dataset.

It travels with the dataset (``push_to_hub`` uploads ``meta/``) and holds, per dataset: the tasks with their
full variation tables, the robots, the collection settings of every source (task, robot) and, per episode,
its task, robot, variation, episode slot, instance seed and the expert's failed attempts, so that any
episode can be regenerated: ``env = make_task_env(task, variation, robot); env.reset_to_seed(seed)`` and
run the task's expert. Layout::

    {"format_version": 1, "repo_id": ..., "robots": [...],
     "tasks": {task: {"horizon_steps": ..., "variations": [{"index", "description", "params"}]}},
     "sources": [{"repo_id", "task", "robot", "settings": {...}}],
     "episodes": [{"episode_index", "task", "robot", "variation", "slot", "seed", "attempts",
                   "failed_seeds", "length"}],
     "software": {...}, "created_utc": ...}
"""

from __future__ import annotations

import json
import platform
from datetime import UTC, datetime
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

from mosaic_data.atomic_files import write_bytes_atomically

SIDECAR_NAME = "mosaic.json"
FORMAT_VERSION = 1
SOFTWARE_PACKAGES = ("mosaic", "lerobot", "robosuite", "mujoco", "metaworld", "numpy", "torch", "av")


def sidecar_path(root: Path) -> Path:
    return Path(root) / "meta" / SIDECAR_NAME


def read_sidecar(root: Path) -> dict[str, Any] | None:
    """The sidecar of the dataset at ``root``, or None when it has none (or it cannot be parsed)."""
    try:
        return json.loads(sidecar_path(root).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def write_json_atomically(path: Path, content: dict[str, Any]) -> None:
    """Write JSON so that a reader (or a crash) never sees half a file."""
    write_bytes_atomically(path, (json.dumps(content, indent=2, default=_json_default) + "\n").encode())


def write_sidecar(root: Path, sidecar: dict[str, Any]) -> None:
    write_json_atomically(sidecar_path(root), sidecar)


def variation_table(task: str) -> dict[str, Any]:
    from mosaic_data.tasks import get_task_class

    task_class = get_task_class(task)
    return {
        "horizon_steps": task_class.horizon_steps,
        "variations": [
            {"index": v.index, "description": v.description, "params": json.loads(json.dumps(v.params, default=_json_default))}
            for v in task_class.variations
        ],
    }


def software_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for package in SOFTWARE_PACKAGES:
        try:
            versions[package] = importlib_metadata.version(package)
        except importlib_metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def build_sidecar(repo_id: str, sources: list[dict[str, Any]], episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """Sidecar of a dataset made from ``sources`` (one for a collected dataset, several for a merged one)."""
    tasks = list(dict.fromkeys(source["task"] for source in sources))
    return {
        "format_version": FORMAT_VERSION,
        "repo_id": repo_id,
        "robots": list(dict.fromkeys(source["robot"] for source in sources)),
        "tasks": {task: variation_table(task) for task in tasks},
        "sources": sources,
        "episodes": episodes,
        "software": software_versions(),
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (set, tuple)):
        return list(value)
    return str(value)
