"""Merging with LeRobot's own aggregation: shards into a collected dataset, datasets into a multi-task one.

Every merge is built in a hidden sibling folder ``.NAME.merging-PID`` and renamed into place at the end, so the
destination is either the old dataset or the complete new one, never half of one; the old one waits in
``.NAME.replaced-PID`` for the instant between the two renames. What a killed merge (or collect) left behind is
cleaned up by the next merge into the same place, once the process that wrote it is gone.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import shutil
from collections import defaultdict
from pathlib import Path
from typing import Any

from mosaic_data.atomic_files import give_plain_modes
from mosaic_data.collection import CollectionError
from mosaic_data.collection.metadata import build_sidecar, read_aligned_sidecar, write_sidecar
from mosaic_data.collection.schema import feature_mismatch, is_lerobot_dataset, repo_id_of

BUILDING_MARK = ".merging-"
RETIRED_MARK = ".replaced-"
DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)


def aggregate_into(
    sources: list[tuple[str, Path]],
    repo_id: str,
    root: Path,
    sidecar: dict[str, Any],
    kept: str = "the source datasets are untouched",
) -> None:
    """Aggregate ``(repo_id, root)`` sources in order into ``root`` with its sidecar, replacing it atomically.

    Every file and folder of the result has the mode a plain ``open()`` or ``mkdir`` gives under the umask, as the
    rest of the dataset has, so that whoever may read the metadata may read the videos too.

    A full disk (or quota) stops the merge with one CollectionError line saying where, and that nothing was lost:
    the partial build is removed, ``root`` keeps what it held, and ``kept`` says where the sources are.
    """
    from lerobot.datasets.aggregate import aggregate_datasets

    building = root.parent / f".{root.name}{BUILDING_MARK}{os.getpid()}"
    root.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_work(root)
    shutil.rmtree(building, ignore_errors=True)
    quiet = _quiet_lerobot_progress()
    try:
        aggregate_datasets(
            repo_ids=[source_repo_id for source_repo_id, _ in sources],
            aggr_repo_id=repo_id,
            roots=[source_root for _, source_root in sources],
            aggr_root=building,
        )
        write_sidecar(building, sidecar)
        give_plain_modes(building)  # LeRobot writes the merged videos through tempfile: mode 0600
        replace_dataset(building, root)
    except Exception as error:
        if not _is_disk_full(error):
            raise
        before = "the dataset there is unchanged" if root.exists() else "nothing was written there"
        raise CollectionError(
            f"no space left on the disk holding {root.parent} while merging into {root.name}: nothing was lost "
            f"({before}, {kept}): free some space and run the same command again"
        ) from None
    finally:
        quiet.restore()
        shutil.rmtree(building, ignore_errors=True)


def _is_disk_full(error: BaseException | None) -> bool:
    """Whether ``error`` (or what caused it) is a full disk or quota: Python's file calls set ``errno``, pyarrow
    and the video library only say it in the message."""
    seen = 0
    while error is not None and seen < 10:
        if isinstance(error, OSError) and error.errno in DISK_FULL_ERRNOS:
            return True
        if any(os.strerror(number) in str(error) for number in DISK_FULL_ERRNOS):
            return True
        error, seen = error.__cause__ or error.__context__, seen + 1
    return False


def remove_stale_work(root: Path) -> list[Path]:
    """Clean what killed merges into ``root`` left beside it; returns what was removed or restored.

    Only folders of processes that are gone are touched (a merge running now keeps its own). A stale build is
    deleted; a stale ``.replaced-`` folder is the previous dataset: deleted if the new one made it into place,
    else renamed back to ``root`` so that a merge killed between its two renames loses nothing.
    """
    handled = []
    for leftover in sorted(root.parent.glob(f".{root.name}.*")):
        for mark in (BUILDING_MARK, RETIRED_MARK):
            prefix = f".{root.name}{mark}"
            pid_text = leftover.name[len(prefix):] if leftover.name.startswith(prefix) else ""
            if pid_text.isdigit() and not _process_alive(int(pid_text)):
                if mark == RETIRED_MARK and not root.exists() and is_lerobot_dataset(leftover):
                    os.rename(leftover, root)
                else:
                    shutil.rmtree(leftover, ignore_errors=True)
                handled.append(leftover)
    return handled


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def check_replaceable(root: Path, flag: str = "--repo-id") -> None:
    """Refuse to ``--overwrite`` anything but one LeRobot dataset folder (or an empty folder) at ``root``.

    A folder that holds other datasets or files the user keeps there is never replaced, whatever the flags.
    """
    if not root.exists() and not root.is_symlink():
        return
    if root.is_symlink() or not root.is_dir():
        raise ValueError(f"{root} is not a dataset folder (a file or a link): move it away or choose another {flag}")
    if is_lerobot_dataset(root) or not any(root.iterdir()):
        return
    raise ValueError(
        f"{root} is not a LeRobot dataset but a folder with other content: --overwrite replaces only a dataset "
        f"folder; move it away or choose another {flag}"
    )


def replace_dataset(built: Path, root: Path) -> None:
    """Move the finished dataset ``built`` to ``root``, which holds the old one (if any) until the last moment."""
    if root.exists():
        retired = root.parent / f".{root.name}{RETIRED_MARK}{os.getpid()}"
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
    aligned = [read_aligned_sidecar(source) for source in source_roots]  # LeRobot-edited sources too
    sidecars = [entry.sidecar for entry in aligned]
    robots = sorted({robot for sidecar in sidecars for robot in sidecar["robots"]})
    if len(robots) > 1:
        raise ValueError(
            f"the datasets hold different robots ({', '.join(robots)}): LeRobot keeps one robot type per dataset, "
            "merge the panda and the sawyer datasets separately"
        )
    if root.resolve() in {path.resolve() for path in source_roots}:
        raise ValueError(f"the merged dataset {root} would overwrite one of its sources: choose another --repo-id")
    _check_same_schema(source_roots)
    _check_no_shared_episodes(source_roots, sidecars)
    sources, episodes, removed, offset = [], [], [], 0
    for entry in aligned:
        sources.extend(entry.sidecar["sources"])
        for record in entry.sidecar["episodes"]:
            episodes.append({**record, "episode_index": offset + record["episode_index"]})
        removed.extend(entry.sidecar.get("removed_episodes", []))
        offset += entry.total_episodes  # LeRobot's count: an episode without a record still takes its index
    merged_sidecar = build_sidecar(repo_id, sources, episodes, removed_episodes=removed)
    try:
        aggregate_into([(repo_id_of(path), path) for path in source_roots], repo_id, root, merged_sidecar)
    except ValueError as error:  # one line, whole: its point may be at the end
        lines = str(error).strip().splitlines() or [type(error).__name__]
        raise ValueError(f"LeRobot cannot aggregate these datasets: {' '.join(line.strip() for line in lines)}") from None
    return merged_sidecar


def _check_same_schema(source_roots: list[Path]) -> None:
    """Name the first feature (or fps) in which a source differs from the first one, with both shapes in full.

    LeRobot's own check prints both whole feature dicts, far too long for one line.
    """
    infos = []
    for source in source_roots:
        try:
            infos.append(json.loads((source / "meta" / "info.json").read_text()))
        except (OSError, ValueError) as error:
            raise ValueError(f"{source}/meta/info.json cannot be read ({error}): validate the dataset, or collect it again") from None
    first = infos[0]
    for source, info in zip(source_roots[1:], infos[1:]):
        mismatch = feature_mismatch(info.get("features") or {}, first.get("features") or {}, extra_allowed=False)
        if mismatch is None and info.get("fps") != first.get("fps"):
            mismatch = f"fps is {info.get('fps')}, expected {first.get('fps')}"
        if mismatch is not None:
            raise ValueError(
                f"the datasets differ: {source}'s {mismatch} as in {source_roots[0]}: "
                "merge datasets collected with the same --image-size"
            )


def _check_no_shared_episodes(source_roots: list[Path], sidecars: list[dict[str, Any]]) -> None:
    """Refuse sources that hold the same episodes (task, robot, variation, seed), e.g. two copies of one collection:
    the merged dataset would fail ``mosaic-data validate`` and weigh those episodes twice in training."""
    holders: dict[tuple, list[int]] = defaultdict(list)
    for index, sidecar in enumerate(sidecars):
        for record in sidecar["episodes"]:
            holders[(record["task"], record["robot"], record["variation"], record["seed"])].append(index)
    pairs: dict[tuple[int, int], list[tuple]] = defaultdict(list)  # (source, other source) -> shared episode keys
    for key, indices in holders.items():
        if len(indices) > 1:
            distinct = sorted(set(indices))
            pairs[(distinct[0], distinct[-1] if len(distinct) > 1 else distinct[0])].append(key)
    if not pairs:
        return
    (first, second), keys = next(iter(pairs.items()))
    if first != second:
        head = f"{source_roots[first]} and {source_roots[second]} hold the same {len(keys)} episode(s)"
    else:
        head = f"{source_roots[first]} holds {len(keys)} episode(s) twice"
    task, robot, variation, seed = keys[0]
    raise ValueError(
        f"{head} (same task, robot, variation and seed; e.g. {task} {robot} "
        f"variation {variation} seed {seed}): merge each collection once, or collect the other with another --seed"
    )


class _quiet_lerobot_progress:
    """LeRobot's aggregation logs every step at INFO; keep the user's terminal for our own progress bar."""

    def __init__(self) -> None:
        self._logger = logging.getLogger("lerobot")
        self._level = self._logger.level
        self._logger.setLevel(logging.WARNING)

    def restore(self) -> None:
        self._logger.setLevel(self._level)
