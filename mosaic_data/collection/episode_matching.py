"""Which record of the sidecar (:mod:`.metadata`) belongs to which episode of the dataset as LeRobot holds it now.

LeRobot's own tools (``lerobot-edit-dataset``: delete_episodes, split, ...) neither copy nor update the sidecar,
and they renumber the episodes. :func:`align_sidecar` therefore matches each current LeRobot episode to its
record by ``data_digest`` (a hash of the episode's actions, which LeRobot copies bit for bit), and a record
without a digest by task string, variation and length. The current episodes are read from the dataset's data
files (:func:`read_current_episodes`); the sidecar itself is read and checked by :mod:`.metadata`.
"""

from __future__ import annotations

import hashlib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

LIST_LIMIT = 5


def listed(items: list, limit: int = LIST_LIMIT) -> str:
    """``[a, b, c]``, or the first ``limit`` then ``...`` and the total, so a cut list never looks complete."""
    items = list(items)
    if len(items) <= limit:
        return "[" + ", ".join(map(str, items)) + "]"
    return "[" + ", ".join(map(str, items[:limit])) + f", ...] ({len(items)} in all)"


@dataclass(frozen=True)
class CurrentEpisode:
    """What the dataset's data says about one of its episodes now, whatever LeRobot did to it."""

    index: int
    length: int
    task: str | None
    variation: int | None
    digest: str


def actions_digest(actions) -> str:
    """Hash of one episode's actions (float32, frame order): LeRobot's edits copy them bit for bit, and two
    episodes (other seed, variation or task) never share them."""
    import numpy as np

    return hashlib.sha256(np.ascontiguousarray(np.asarray(actions, dtype="<f4")).tobytes()).hexdigest()[:16]


def current_episodes(frames, tasks: dict[int, str]) -> list[CurrentEpisode]:
    """The episodes in ``frames`` (the data parquet files, concatenated), in index order. One pass over sorted
    arrays: a merged dataset holds thousands of episodes, and every command reads this."""
    import numpy as np

    if frames is None or not len(frames):
        return []
    frames = frames.sort_values(["episode_index", "frame_index"], kind="stable")
    episode_ids = frames["episode_index"].to_numpy()
    starts = np.flatnonzero(np.r_[True, episode_ids[1:] != episode_ids[:-1]])
    ends = np.r_[starts[1:], len(episode_ids)]
    actions = np.asarray(frames["action"].tolist(), dtype="<f4") if "action" in frames else None
    variations = frames["variation"].to_numpy() if "variation" in frames else None
    task_indices = frames["task_index"].to_numpy() if "task_index" in frames else None
    episodes = []
    for start, end in zip(starts.tolist(), ends.tolist()):
        variation = None if variations is None else int(np.asarray(variations[start]).reshape(-1)[0])
        task = None if task_indices is None else tasks.get(int(task_indices[start]))
        digest = "" if actions is None else actions_digest(actions[start:end])
        episodes.append(CurrentEpisode(int(episode_ids[start]), end - start, task, variation, digest))
    return episodes


def read_task_strings(root: Path) -> dict[int, str]:
    """LeRobot's task table: task index -> task string (the variation's description)."""
    import pandas as pd

    tasks = pd.read_parquet(Path(root) / "meta" / "tasks.parquet")
    return {int(index): str(task) for task, index in zip(tasks.index, tasks["task_index"])}


def read_current_episodes(root: Path) -> list[CurrentEpisode]:
    """The dataset's episodes as its data holds them now (reads only the few columns needed)."""
    import pandas as pd
    import pyarrow.parquet as pq

    wanted = ["episode_index", "frame_index", "task_index", "variation", "action"]
    tables = []
    for path in sorted((Path(root) / "data").glob("*/*.parquet")):
        columns = [name for name in wanted if name in pq.read_schema(path).names]
        tables.append(pq.read_table(path, columns=columns).to_pandas())
    frames = pd.concat(tables, ignore_index=True) if tables else None
    return current_episodes(frames, read_task_strings(root))


@dataclass
class AlignedSidecar:
    """A sidecar matched to the dataset's current LeRobot episodes.

    ``sidecar`` is the stored one with ``episodes`` replaced by the records of the current episodes, in order,
    each with its current ``episode_index``; the records of episodes that are gone move to ``removed_episodes``
    (kept: they say what was collected). Commands use ``sidecar`` exactly like a freshly collected one.
    """

    sidecar: dict[str, Any]
    path: Path
    from_backup: bool
    total_episodes: int
    unrecorded: list[int] = field(default_factory=list)
    newly_removed: list[dict[str, Any]] = field(default_factory=list)
    renumbered: int = 0
    loosely_matched: list[int] = field(default_factory=list)
    changed_data: list[int] = field(default_factory=list)

    @property
    def changed(self) -> bool:
        """Whether the stored file differs from ``sidecar`` (a LeRobot edit removed or renumbered episodes)."""
        return bool(self.from_backup or self.newly_removed or self.renumbered)

    def warnings(self, root: Path, include_backup: bool = True) -> list[str]:
        """What a user should know about the match; none for a dataset as collected. ``include_backup=False``
        leaves out the advice to copy a sidecar read from LeRobot's backup (for a caller that writes it)."""
        lines = []
        if self.from_backup and include_backup:
            lines.append(
                f"{root} has no meta/mosaic.json (LeRobot's edits do not copy it): using the one in LeRobot's backup "
                f"{self.path.parent.parent}; copy it into {Path(root) / 'meta'}/ to keep it with the dataset "
                "(another in-place edit replaces that backup)"
            )
        if self.newly_removed:
            gone = [f"{r['task']}/{r['robot']} variation {r['variation']} seed {r['seed']}" for r in self.newly_removed]
            lines.append(
                f"{_count(len(gone), 'episode')} of meta/mosaic.json {'is' if len(gone) == 1 else 'are'} no longer in "
                f"the dataset (removed by an edit such as lerobot-edit-dataset delete_episodes): {listed(gone)}"
            )
        if self.unrecorded:
            lines.append(
                f"{_count(len(self.unrecorded), 'episode')} {'has' if len(self.unrecorded) == 1 else 'have'} no sidecar "
                f"record (their seeds are unknown): episodes {listed(self.unrecorded)}"
            )
        if self.loosely_matched:
            one = len(self.loosely_matched) == 1
            lines.append(
                f"{_count(len(self.loosely_matched), 'episode')} {'was' if one else 'were'} matched to "
                f"{'its record' if one else 'their records'} by task, variation and length only (meta/mosaic.json "
                "predates data digests) while a removed episode looked the same, so a seed may be the removed "
                f"episode's: episodes {listed(self.loosely_matched)}"
            )
        return lines


def _count(number: int, noun: str) -> str:
    return f"{number} {noun}{'' if number == 1 else 's'}"


def variation_descriptions(sidecar: dict[str, Any]) -> dict[tuple[str, int], str]:
    """``(task, variation) -> description`` (the LeRobot task string) from the sidecar's variation tables."""
    return {
        (task, variation["index"]): variation["description"]
        for task, table in sidecar.get("tasks", {}).items()
        for variation in table["variations"]
    }


def align_sidecar(sidecar: dict[str, Any], current: list[CurrentEpisode], path: Path, from_backup: bool = False) -> AlignedSidecar:
    """Match the records of ``sidecar`` (checked) to the ``current`` episodes.

    First by data digest. The rest by look (task string, variation, length): with as many records as episodes
    (nothing removed) at the same index, else in order, as LeRobot keeps the order of the episodes it keeps (a
    record skipped over is an episode removed). Last, with as many records as episodes, whatever is left at the
    same index: one episode whose data changed, which ``validate`` reports.
    """
    records = sidecar["episodes"]
    descriptions = variation_descriptions(sidecar)

    def looks_like(record: dict[str, Any], episode: CurrentEpisode) -> bool:
        return (
            record["length"] == episode.length
            and record["variation"] == episode.variation
            and descriptions.get((record["task"], record["variation"])) == episode.task
        )

    matched: dict[int, int] = {}  # current episode index -> record position
    used: set[int] = set()

    def match(episode: CurrentEpisode, position: int) -> None:
        matched[episode.index] = position
        used.add(position)

    by_digest: dict[str, list[int]] = defaultdict(list)
    for position, record in enumerate(records):
        if record.get("data_digest"):
            by_digest[record["data_digest"]].append(position)
    for episode in current:
        position = next((p for p in by_digest.get(episode.digest, ()) if p not in used), None)
        if position is not None:
            match(episode, position)
    by_index = {record["episode_index"]: position for position, record in enumerate(records)}
    same_count = len(records) == len(current)
    if same_count:
        for episode in current:
            position = by_index.get(episode.index)
            if episode.index not in matched and position is not None and position not in used and looks_like(records[position], episode):
                match(episode, position)
    free = [position for position in range(len(records)) if position not in used]  # in record order
    cursor = 0
    for episode in current:
        if episode.index in matched:
            continue
        ahead = next((k for k in range(cursor, len(free)) if looks_like(records[free[k]], episode)), None)
        if ahead is not None:  # no record ahead looks like it: an episode without one, the cursor stays
            match(episode, free[ahead])
            cursor = ahead + 1
    if same_count:
        for episode in current:
            position = by_index.get(episode.index)
            if episode.index not in matched and position is not None and position not in used:
                match(episode, position)

    newly_removed = [record for position, record in enumerate(records) if position not in used]
    removed_looks = {(r["task"], r["variation"], r["length"]) for r in newly_removed}
    aligned = AlignedSidecar(sidecar={}, path=Path(path), from_backup=from_backup, total_episodes=len(current), newly_removed=newly_removed)
    aligned_records = []
    for episode in current:
        position = matched.get(episode.index)
        if position is None:
            aligned.unrecorded.append(episode.index)
            continue
        record = records[position]
        aligned.renumbered += record["episode_index"] != episode.index
        if record.get("data_digest"):
            if record["data_digest"] != episode.digest:
                aligned.changed_data.append(episode.index)
        elif (record["task"], record["variation"], record["length"]) in removed_looks:
            aligned.loosely_matched.append(episode.index)
        aligned_records.append({**record, "episode_index": episode.index})
    aligned.sidecar = {**sidecar, "episodes": aligned_records}
    if newly_removed or sidecar.get("removed_episodes"):
        aligned.sidecar["removed_episodes"] = list(sidecar.get("removed_episodes") or []) + newly_removed
    return aligned
