"""Merging with LeRobot's own aggregation: shards into a collected dataset, datasets into a multi-task one.

Every merge is built in a hidden sibling folder and renamed into place at the end, so the destination is
either the old dataset or the complete new one, never half of one.
"""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path
from typing import Any

from mosaic_data.collection.metadata import build_sidecar, read_sidecar, write_sidecar
from mosaic_data.collection.schema import repo_id_of


def aggregate_into(sources: list[tuple[str, Path]], repo_id: str, root: Path, sidecar: dict[str, Any]) -> None:
    """Aggregate ``(repo_id, root)`` sources in order into ``root`` with its sidecar, replacing it atomically."""
    from lerobot.datasets.aggregate import aggregate_datasets

    building = root.parent / f".{root.name}.merging-{os.getpid()}"
    shutil.rmtree(building, ignore_errors=True)
    root.parent.mkdir(parents=True, exist_ok=True)
    quiet = _quiet_lerobot_progress()
    try:
        aggregate_datasets(
            repo_ids=[source_repo_id for source_repo_id, _ in sources],
            aggr_repo_id=repo_id,
            roots=[source_root for _, source_root in sources],
            aggr_root=building,
        )
        write_sidecar(building, sidecar)
        replace_dataset(building, root)
    finally:
        quiet.restore()
        shutil.rmtree(building, ignore_errors=True)


def replace_dataset(built: Path, root: Path) -> None:
    """Move the finished dataset ``built`` to ``root``, which holds the old one (if any) until the last moment."""
    if root.exists():
        retired = root.parent / f".{root.name}.replaced-{os.getpid()}"
        shutil.rmtree(retired, ignore_errors=True)
        os.rename(root, retired)
        os.rename(built, root)
        shutil.rmtree(retired, ignore_errors=True)
    else:
        os.rename(built, root)


def merge_datasets(source_roots: list[Path], repo_id: str, root: Path) -> dict[str, Any]:
    """Merge MOSAIC datasets (same robot, same image size) into one at ``root``; returns its sidecar."""
    if len(source_roots) < 2:
        raise ValueError("merge needs at least two datasets")
    if len({path.resolve() for path in source_roots}) != len(source_roots):
        raise ValueError("the same dataset is listed twice: every dataset may be merged only once")
    sidecars = []
    for source in source_roots:
        sidecar = read_sidecar(source)
        if sidecar is None:
            raise ValueError(f"{source} has no meta/mosaic.json: only datasets made by `mosaic-data collect` can be merged")
        sidecars.append(sidecar)
    robots = sorted({robot for sidecar in sidecars for robot in sidecar["robots"]})
    if len(robots) > 1:
        raise ValueError(
            f"the datasets hold different robots ({', '.join(robots)}): LeRobot keeps one robot type per dataset, "
            "merge the panda and the sawyer datasets separately"
        )
    if root.resolve() in {path.resolve() for path in source_roots}:
        raise ValueError(f"the merged dataset {root} would overwrite one of its sources: choose another --repo-id")
    sources, episodes, offset = [], [], 0
    for sidecar in sidecars:
        sources.extend(sidecar["sources"])
        for record in sidecar["episodes"]:
            episodes.append({**record, "episode_index": offset + record["episode_index"]})
        offset += len(sidecar["episodes"])
    merged_sidecar = build_sidecar(repo_id, sources, episodes)
    try:
        aggregate_into([(repo_id_of(path), path) for path in source_roots], repo_id, root, merged_sidecar)
    except ValueError as error:  # LeRobot's compatibility checks print whole feature dicts: keep one line
        raise ValueError(f"LeRobot cannot aggregate these datasets: {str(error).splitlines()[0][:300]}") from None
    return merged_sidecar


class _quiet_lerobot_progress:
    """LeRobot's aggregation logs every step at INFO; keep the user's terminal for our own progress bar."""

    def __init__(self) -> None:
        self._logger = logging.getLogger("lerobot")
        self._level = self._logger.level
        self._logger.setLevel(logging.WARNING)

    def restore(self) -> None:
        self._logger.setLevel(self._level)
