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
                   "failed_seeds", "length", "data_digest"}],
     "removed_episodes": [...],  # only after an edit: records of episodes no longer in the dataset
     "software": {...}, "created_utc": ...}

A source's settings hold ``action_noise`` (the stds and how the noise was drawn) only when it was collected with
``--action-noise`` (DART-style noise on the executed actions; ``action`` is then the expert's clean action).

LeRobot's own tools (``lerobot-edit-dataset``: delete_episodes, split, ...) neither copy nor update the sidecar,
and they renumber the episodes. :func:`read_aligned_sidecar` therefore matches each current LeRobot episode to
its record by ``data_digest`` (a hash of the episode's actions, which LeRobot copies bit for bit), falling back
to task string, variation and length for sidecars written before digests; validate, view, merge and push read
the sidecar through it, so an edited dataset stays usable.
"""

from __future__ import annotations

import hashlib
import json
import platform
from collections import defaultdict
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

from mosaic_data.atomic_files import write_bytes_atomically

SIDECAR_NAME = "mosaic.json"
FORMAT_VERSION = 1
SOFTWARE_PACKAGES = ("mosaic", "lerobot", "robosuite", "mujoco", "metaworld", "numpy", "torch", "av")


def sidecar_path(root: Path) -> Path:
    """``<root>/meta/mosaic.json``: inside ``meta/`` so that LeRobot's ``push_to_hub`` uploads it."""
    return Path(root) / "meta" / SIDECAR_NAME


def read_sidecar(root: Path) -> dict[str, Any] | None:
    """The sidecar of the dataset at ``root`` as stored, or None when it has none, it cannot be parsed or it is
    not a JSON object (callers index it like one). Commands use :func:`read_aligned_sidecar` instead."""
    try:
        sidecar = json.loads(sidecar_path(root).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return sidecar if isinstance(sidecar, dict) else None


def write_json_atomically(path: Path, content: dict[str, Any]) -> None:
    """Write JSON so that a reader (or a crash) never sees half a file."""
    write_bytes_atomically(path, (json.dumps(content, indent=2, default=_json_default) + "\n").encode())


def write_sidecar(root: Path, sidecar: dict[str, Any]) -> None:
    """Write the sidecar of the finished dataset at ``root`` atomically.

    Records without a ``data_digest`` get one from the data at ``root`` first (in place, so the caller's dict
    has it too): it is what finds an episode's record again after LeRobot's tools renumber the episodes.
    """
    add_data_digests(root, sidecar)
    write_json_atomically(sidecar_path(root), sidecar)


def add_data_digests(root: Path, sidecar: dict[str, Any]) -> None:
    """Give every record of ``sidecar`` that lacks one the digest of its episode's data at ``root``.

    Best effort: a dataset whose data cannot be read keeps records without digests (``validate`` reports it).
    """
    missing = [record for record in sidecar.get("episodes", []) if "data_digest" not in record]
    if not missing or not (Path(root) / "data").is_dir():
        return
    try:
        current = {episode.index: episode for episode in read_current_episodes(root)}
    except Exception:  # pyarrow raises several types for damaged files; the digests are an aid, not a must
        return
    for record in missing:
        episode = current.get(record.get("episode_index"))
        if episode is not None and episode.length == record.get("length"):
            record["data_digest"] = episode.digest


def variation_table(task: str) -> dict[str, Any]:
    from mosaic_data.tasks.spec import get_task_spec  # the table only, not the simulator

    spec = get_task_spec(task)
    return {
        "horizon_steps": spec.horizon_steps,
        "variations": [
            {"index": v.index, "description": v.description, "params": json.loads(json.dumps(v.params, default=_json_default))}
            for v in spec.variations
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


def build_sidecar(
    repo_id: str,
    sources: list[dict[str, Any]],
    episodes: list[dict[str, Any]],
    removed_episodes: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Sidecar of a dataset made from ``sources`` (one for a collected dataset, several for a merged one).

    ``removed_episodes``: records of source episodes that a LeRobot edit removed before the merge; kept so
    that the counts per variation still add up to the collection settings.
    """
    tasks = list(dict.fromkeys(source["task"] for source in sources))
    sidecar = {
        "format_version": FORMAT_VERSION,
        "repo_id": repo_id,
        "robots": list(dict.fromkeys(source["robot"] for source in sources)),
        "tasks": {task: variation_table(task) for task in tasks},
        "sources": sources,
        "episodes": episodes,
        "software": software_versions(),
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    if removed_episodes:
        sidecar["removed_episodes"] = removed_episodes
    return sidecar


# ---------------------------------------------------------------------- reading it back, after any edit

LEROBOT_BACKUP_SUFFIX = "_old"
"""``lerobot-edit-dataset`` editing in place moves the original to ``<root>_old`` and writes the edited dataset
without the sidecar; the original sidecar then lives on in that backup."""
SETTINGS_KEYS = ("variations", "episodes_per_variation", "image_height", "image_width", "fps")
RECORD_KEYS = ("episode_index", "task", "robot", "variation", "seed", "attempts", "length")
SIDECAR_FIX = "restore it from a copy of the dataset, or collect the dataset again with `mosaic-data collect`"
LIST_LIMIT = 5


class SidecarError(ValueError):
    """No usable sidecar: the message is one line naming the file and what to do (commands exit with status 2)."""


def listed(items: list, limit: int = LIST_LIMIT) -> str:
    """``[a, b, c]``, or the first ``limit`` then ``...`` and the total, so a cut list never looks complete."""
    items = list(items)
    if len(items) <= limit:
        return "[" + ", ".join(map(str, items)) + "]"
    return "[" + ", ".join(map(str, items[:limit])) + f", ...] ({len(items)} in all)"


def sidecar_format_problem(sidecar: Any) -> str | None:
    """What keeps ``sidecar`` from being MOSAIC's layout, or None: checked once, so no command meets a KeyError."""
    json_types = {list: "a list", str: "a string", int: "a number", float: "a number", bool: "a boolean", type(None): "null"}
    if not isinstance(sidecar, dict):
        return f"it holds {json_types.get(type(sidecar), type(sidecar).__name__)}, not an object"
    if (problem := _format_version_problem(sidecar)) is not None:
        return problem
    for key, kind in (("tasks", dict), ("robots", list), ("sources", list), ("episodes", list)):
        if not isinstance(sidecar.get(key), kind):
            return f"it has no '{key}'" if key not in sidecar else f"its '{key}' is not {'an object' if kind is dict else 'a list'}"
    if not sidecar["sources"]:
        return "it lists no sources, so not the collection settings"
    for number, source in enumerate(sidecar["sources"]):
        settings = source.get("settings") if isinstance(source, dict) else None
        if not isinstance(settings, dict):
            return f"source {number} has no collection settings"
        if missing := [key for key in SETTINGS_KEYS if key not in settings]:
            return f"the collection settings of source {number} lack {', '.join(missing)}"
        if not {"task", "robot"} <= set(source):
            return f"source {number} does not say its task and robot"
    descriptions = {}
    for task, table in sidecar["tasks"].items():
        variations = table.get("variations") if isinstance(table, dict) else None
        if not isinstance(variations, list) or not all(isinstance(v, dict) and {"index", "description"} <= set(v) for v in variations):
            return f"the variation table of task {task!r} is not a list of variations with index and description"
        descriptions.update({(task, v["index"]): v["description"] for v in variations})
    for key in ("episodes", "removed_episodes"):
        for number, record in enumerate(sidecar.get(key) or []):
            if not isinstance(record, dict) or (missing := [name for name in RECORD_KEYS if name not in record]):
                what = "is not an object" if not isinstance(record, dict) else f"lacks {', '.join(missing)}"
                return f"its record {number} of '{key}' {what}"
            if (record["task"], record["variation"]) not in descriptions:
                return f"its record {number} of '{key}' is {record['task']} variation {record['variation']}, which no variation table holds"
    return None


def _format_version_problem(sidecar: dict[str, Any]) -> str | None:
    """Why the sidecar's ``format_version`` is not the one this code reads, or None. Checked first: a sidecar of
    another layout must not be read as this one, nor fail on a field it names differently."""
    if "format_version" not in sidecar:
        return f"it has no 'format_version', expected {FORMAT_VERSION}"
    version = sidecar["format_version"]
    if type(version) is not int or version != FORMAT_VERSION:  # not bool or float: JSON true or 1.0 is no version
        text = json.dumps(version)
        return f"its 'format_version' is {text if len(text) <= 40 else text[:37] + '...'}, expected {FORMAT_VERSION}"
    return None


def load_sidecar(path: Path) -> dict[str, Any]:
    """The sidecar in the file ``path``, checked; raises SidecarError naming the file and the fix."""
    try:
        sidecar = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError) as error:
        raise SidecarError(f"{path} cannot be read ({error}): {SIDECAR_FIX}") from None
    except json.JSONDecodeError as error:
        raise SidecarError(f"{path} is not valid JSON ({error}): {SIDECAR_FIX}") from None
    if (problem := sidecar_format_problem(sidecar)) is not None:
        raise SidecarError(f"{path} is not a MOSAIC sidecar ({problem}): {SIDECAR_FIX}")
    return sidecar


def backup_root(root: Path) -> Path:
    """Where an in-place ``lerobot-edit-dataset`` leaves the dataset it edited."""
    return Path(root).with_name(Path(root).name + LEROBOT_BACKUP_SUFFIX)


def locate_sidecar(root: Path) -> tuple[Path, bool]:
    """``(file, from_backup)``: the dataset's own sidecar, else the one in LeRobot's in-place backup."""
    own = sidecar_path(root)
    if own.exists():
        return own, False
    backup = sidecar_path(backup_root(root))
    if backup.is_file():
        return backup, True
    raise SidecarError(
        f"{root} has no meta/mosaic.json, so it is not a dataset made by `mosaic-data collect`; if it is one "
        f"edited with lerobot-edit-dataset (which does not copy that file), copy meta/mosaic.json of the original "
        f"into {Path(root) / 'meta'}/: its records are matched to the remaining episodes"
    )


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


def read_aligned_sidecar(root: Path) -> AlignedSidecar:
    """The sidecar of the dataset at ``root`` matched to its current LeRobot episodes: what every command reads,
    so that datasets edited with LeRobot's tools stay usable. Raises SidecarError (one line: the file, the fix)."""
    root = Path(root)
    path, from_backup = locate_sidecar(root)
    sidecar = load_sidecar(path)
    try:
        current = read_current_episodes(root)
    except Exception as error:  # pyarrow raises several types for damaged files
        first_line = (str(error).strip().splitlines() or [type(error).__name__])[0]
        raise SidecarError(f"the data of {root} cannot be read ({first_line}): `mosaic-data validate {root}` says what is damaged") from None
    aligned = align_sidecar(sidecar, current, path, from_backup)
    if current and not aligned.sidecar["episodes"]:
        raise SidecarError(
            f"{path} describes none of the {len(current)} episodes of {root}: it belongs to another dataset; "
            f"copy meta/mosaic.json of the dataset {root} was collected (or edited) from into {root / 'meta'}/"
        )
    return aligned


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (set, tuple)):
        return list(value)
    return str(value)
