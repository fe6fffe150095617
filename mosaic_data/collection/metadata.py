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
and they renumber the episodes. :func:`read_aligned_sidecar` finds the sidecar (the dataset's own, else the one in
LeRobot's in-place backup), checks it, and matches its records to the current LeRobot episodes
(:mod:`.episode_matching`); validate, view, merge and push read the sidecar through it, so an edited dataset
stays usable.
"""

from __future__ import annotations

import json
import platform
from datetime import UTC, datetime
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

from mosaic_data.atomic_files import json_default, write_json_atomically
from mosaic_data.collection.episode_matching import AlignedSidecar, align_sidecar, read_current_episodes

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
            {"index": v.index, "description": v.description, "params": json.loads(json.dumps(v.params, default=json_default))}
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


class SidecarError(ValueError):
    """No usable sidecar: the message is one line naming the file and what to do (commands exit with status 2)."""


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

