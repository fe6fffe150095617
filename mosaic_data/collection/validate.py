"""``mosaic-data validate``: is a dataset whole and consistent? Returns a readable list of problems.

Checks, in order: LeRobot's metadata loads; the sidecar exists, is MOSAIC's and matches the current episodes
(also after LeRobot's own edits, which renumber episodes: see :func:`~mosaic_data.collection.metadata.read_aligned_sidecar`);
the schema is MOSAIC's; every data parquet file reads (a truncated file does not) and holds the frames the
metadata announces, episode by episode (frame indices, ``next.done`` on the last frame only, one variation and
the matching task string per episode, the actions collected, no action jump that no motion explains); every
episode count per variation matches the collection settings (episodes removed by an edit count as collected);
every video file decodes, at the right size, to exactly the frames of the episodes it holds.

What is unusual but not wrong (episodes removed by an edit, episodes without a sidecar record, a sidecar read
from LeRobot's backup) goes to ``warnings``, not to the problems.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from mosaic_data.collection.episode_matching import align_sidecar, current_episodes, listed, variation_descriptions
from mosaic_data.collection.metadata import SidecarError, load_sidecar, locate_sidecar
from mosaic_data.collection.schema import ACTION_NAMES, CAMERA_KEY, schema_mismatch

MAX_ACTION_JUMP = {"position": 0.1, "rotation": 0.5}
"""Largest change of the action between two consecutive frames that a motion explains: metres for x, y, z and
radians for each rotation component. The experts move the target at most 1.5 cm and 0.08 rad per step (plus a
slowly integrated tracking offset); a jump past these is a chart flip (axis-angle near pi) or corrupt data.
The gripper is exempt: it switches between -1 and +1 in one step."""
FRAME_COLUMNS = ("episode_index", "frame_index", "task_index", "action", "variation", "next.success", "next.done")
"""Data columns the episode checks read."""


def validate_dataset(root: Path, warnings: list[str] | None = None) -> tuple[str, list[str]]:
    """``(summary, problems)`` for the dataset at ``root``; no problems means it is valid.

    ``warnings``, if given, receives what is worth saying but does not make the dataset invalid.
    """
    import json

    root = Path(root)
    warnings = [] if warnings is None else warnings
    problems: list[str] = []
    try:
        info = json.loads((root / "meta" / "info.json").read_text())
    except (OSError, ValueError) as error:
        return "", [f"meta/info.json cannot be read: {error}"]
    if not isinstance(info, dict) or not isinstance(info.get("features"), dict):
        return "", ["meta/info.json has no feature table: it is not a LeRobot v3 dataset"]
    try:
        sidecar_file, from_backup = locate_sidecar(root)
        sidecar = load_sidecar(sidecar_file)
    except SidecarError as error:
        problems.append(str(error))
        sidecar_file, from_backup, sidecar = None, False, None
    sources = sidecar["sources"] if sidecar is not None else []
    if sources:
        settings = sources[0]["settings"]
        mismatch = schema_mismatch(root, settings["image_height"], settings["image_width"])
        if mismatch is not None:
            problems.append(f"schema: {mismatch}")
    episodes_meta = _read_parquet_folder(root, "meta/episodes", problems)
    data = _read_parquet_folder(root, "data", problems)
    tasks = _read_tasks(root, problems)
    total_episodes, total_frames = info.get("total_episodes"), info.get("total_frames")
    if episodes_meta is not None and len(episodes_meta) != total_episodes:
        problems.append(f"meta/episodes lists {len(episodes_meta)} episodes, info.json says {total_episodes}")
    if data is not None and len(data) != total_frames:
        problems.append(f"data holds {len(data)} frames, info.json says {total_frames}")
    records: list[dict] = []
    if data is not None and (missing := [name for name in FRAME_COLUMNS if name not in data.columns]):
        problems.append(f"data/ has no column {', '.join(missing)}: it is not MOSAIC's schema, so its episodes were not checked")
        data = None
    if sidecar is not None and data is not None:
        current = current_episodes(data, tasks)
        aligned = align_sidecar(sidecar, current, sidecar_file, from_backup)
        warnings.extend(aligned.warnings(root))
        records = aligned.sidecar["episodes"]
        if current and not records:
            problems.append(f"{sidecar_file} describes none of the {len(current)} episodes: it belongs to another dataset")
        descriptions = variation_descriptions(sidecar)
        holds = _check_frames(data, records, tasks, descriptions, problems)
        if (warning := hold_warning(holds)) is not None:
            warnings.append(warning)
        if aligned.changed_data:
            problems.append(
                f"episodes {listed(aligned.changed_data)}: their actions differ from the ones collected (data_digest "
                "in meta/mosaic.json): the data was changed after collection; collect the dataset again"
            )
        by_description = {description: key for key, description in descriptions.items()}
        robots, without_record = sidecar["robots"], set(aligned.unrecorded)
        unrecorded = [  # (task, robot, variation); one robot per LeRobot dataset: the sidecar's, if it names one
            (by_description[episode.task][0], robots[0], by_description[episode.task][1])
            for episode in current
            if episode.index in without_record and episode.task in by_description and len(robots) == 1
        ]
        _check_counts(sources, records, aligned.sidecar.get("removed_episodes", []), unrecorded, problems)
    if episodes_meta is not None:
        _check_videos(root, info, episodes_meta, problems)
    collected_variations = {(record["task"], record["variation"]) for record in records}
    task_names = ", ".join(sidecar["tasks"]) if sidecar is not None else ""
    robot_names = ", ".join(sidecar["robots"]) if sidecar is not None else ""
    summary = (
        f"{_plural(total_episodes, 'episode')}, {_plural(total_frames, 'frame')}, "
        f"{_plural(len(collected_variations), 'variation')} of {task_names or 'no known task'}, "
        f"robots {robot_names or 'unknown'}"
    )
    return summary, problems


def _read_parquet_folder(root: Path, folder: str, problems: list[str]):
    """All parquet files of ``root/folder`` as one frame, or None (with the reason in ``problems``)."""
    import pandas as pd
    import pyarrow.parquet as pq

    files = sorted((root / folder).glob("*/*.parquet"))
    if not files:
        problems.append(f"{folder}/: no parquet files")
        return None
    tables = []
    for path in files:
        try:
            tables.append(pq.read_table(path).to_pandas())
        except Exception as error:  # pyarrow raises several types for truncated or garbled files
            problems.append(f"{path.relative_to(root)} cannot be read ({_first_line(error)})")
    if len(tables) != len(files):
        return None
    return pd.concat(tables, ignore_index=True)


def _first_line(error: BaseException) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0]


def _read_tasks(root: Path, problems: list[str]) -> dict[int, str]:
    import pandas as pd

    try:
        tasks = pd.read_parquet(root / "meta" / "tasks.parquet")
    except Exception as error:
        problems.append(f"meta/tasks.parquet cannot be read ({_first_line(error)})")
        return {}
    return {int(index): str(task) for task, index in zip(tasks.index, tasks["task_index"])}


def _check_frames(
    data, records: list[dict], tasks: dict[int, str], descriptions: dict, problems: list[str]
) -> dict[int, int]:
    """Checks every recorded episode's frames; returns each episode's longest hold (:func:`longest_hold`)."""
    import numpy as np

    holds: dict[int, int] = {}

    by_episode = {int(index): frames for index, frames in data.groupby("episode_index")}
    for record in records:
        index = record["episode_index"]
        frames = by_episode.get(index)
        where = f"episode {index}"
        if frames is None:
            problems.append(f"{where}: no frames in data/")
            continue
        frames = frames.sort_values("frame_index")
        if len(frames) != record["length"]:
            problems.append(f"{where}: {len(frames)} frames, meta/mosaic.json says {record['length']}")
        if not np.array_equal(frames["frame_index"].to_numpy(), np.arange(len(frames))):
            problems.append(f"{where}: frame indices are not 0..{len(frames) - 1}")
        done = np.asarray(frames["next.done"].tolist()).reshape(-1)
        if not done[-1] or done[:-1].any():
            problems.append(f"{where}: next.done must be true on the last frame only")
        if not np.asarray(frames["next.success"].tolist()).reshape(-1)[-1]:
            problems.append(f"{where}: does not end in success (only successful episodes belong in the dataset)")
        variations = set(np.asarray(frames["variation"].tolist()).reshape(-1).tolist())
        if variations != {record["variation"]}:
            problems.append(f"{where}: variation column {sorted(variations)}, meta/mosaic.json says {record['variation']}")
        actions = np.asarray(frames["action"].tolist(), dtype=float)
        _check_action_jumps(actions, where, problems)
        holds[index] = longest_hold(actions)[0]
        task_strings = {tasks.get(int(task_index), "?") for task_index in frames["task_index"]}
        expected = descriptions.get((record["task"], record["variation"]))
        if task_strings != {expected}:
            problems.append(f"{where}: task string {sorted(task_strings)}, expected {expected!r}")
    return holds


def action_jumps(actions) -> dict[str, float]:
    """Largest change between consecutive frames of each action dimension (by name) of one episode."""
    import numpy as np

    actions = np.asarray(actions, dtype=float).reshape(len(actions), -1)
    if len(actions) < 2:
        return {name: 0.0 for name in ACTION_NAMES}
    return dict(zip(ACTION_NAMES, np.abs(np.diff(actions, axis=0)).max(axis=0).tolist(), strict=True))


HOLD_STILL_M = 0.0025
"""A control step whose position target moves less than this holds the hand still."""
HOLD_IGNORED_FIRST, HOLD_IGNORED_LAST = 3, 10
"""Steps at an episode's start (the arm leaving rest) and end (the goal reached) that holds are not counted in."""


def still_steps(actions) -> np.ndarray:
    """Per step of an episode: whether its position target moved less than ``HOLD_STILL_M`` from the step before."""
    import numpy as np

    positions = np.asarray(actions, dtype=float).reshape(len(actions), -1)[:, :3]
    moves = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    return np.concatenate([[False], moves < HOLD_STILL_M])


def longest_hold(actions) -> tuple[int, int]:
    """``(length, first step)`` of the longest run of still steps of an episode, outside its first
    ``HOLD_IGNORED_FIRST`` and last ``HOLD_IGNORED_LAST`` steps; ``(0, -1)`` if there is none.

    A policy sees one frame: where the hand holds still while the only change is one a frame barely shows
    (fingers closing in the air, a settle), the next action is ambiguous from the image and a policy stalls
    there. The statistic finds such holds in expert data."""
    still = still_steps(actions)
    still[:HOLD_IGNORED_FIRST] = False
    if HOLD_IGNORED_LAST:
        still[max(0, len(still) - HOLD_IGNORED_LAST):] = False
    best, best_start, run = 0, -1, 0
    for step, is_still in enumerate(still):
        run = run + 1 if is_still else 0
        if run > best:
            best, best_start = run, step - run + 1
    return best, best_start


POLICY_STEP = 5
"""Control steps per policy query (the policies' default ``action_chunk``; the paper repeats each action 5 times)."""


def hold_warning(holds: dict[int, int]) -> str | None:
    """One line naming the episodes whose longest hold is longer than a policy step, or None."""
    long = {index: hold for index, hold in holds.items() if hold > POLICY_STEP}
    if not long:
        return None
    worst = max(long, key=long.get)
    return (
        f"{_plural(len(long), 'episode')} of {len(holds)} hold the hand still longer than a policy step "
        f"({POLICY_STEP} control steps; longest: {long[worst]} steps in episode {worst}): a policy that sees one frame "
        "may stall where the frame barely changes (see 'Experts a policy can imitate' in the README)"
    )


def _check_action_jumps(actions, where: str, problems: list[str]) -> None:
    jumps = action_jumps(actions)
    for name, jump in jumps.items():
        kind = "position" if name in ("x", "y", "z") else "rotation" if name.startswith("r") else None
        if kind is not None and jump > MAX_ACTION_JUMP[kind]:
            unit = "m" if kind == "position" else "rad"
            problems.append(
                f"{where}: action {name} jumps by {jump:.3f} {unit} in one step (at most {MAX_ACTION_JUMP[kind]} {unit} "
                "is a motion); a rotation chart flip or corrupt data: collect it again with this version"
            )


def _check_counts(
    sources: list[dict], records: list[dict], removed: list[dict], unrecorded: list[tuple], problems: list[str]
) -> None:
    """Episodes per (task, robot, variation) against the collection settings. Those an edit removed (their records
    are kept) and those without a record (known by task string) count as collected: the warnings name them."""
    def key(record: dict) -> tuple:
        return record["task"], record["robot"], record["variation"]

    counts = Counter(map(key, records))
    gone = Counter(map(key, removed))
    extra = Counter(unrecorded)
    expected: Counter = Counter()  # a merged dataset may hold several sources of the same variation
    for source in sources:
        for variation in source["settings"]["variations"]:
            expected[(source["task"], source["robot"], variation)] += source["settings"]["episodes_per_variation"]
    for (task, robot, variation), wanted in sorted(expected.items()):
        here = counts[(task, robot, variation)] + extra[(task, robot, variation)]
        removed_here = gone[(task, robot, variation)]
        if here + removed_here != wanted:
            also = f" (and {removed_here} removed after collection)" if removed_here else ""
            problems.append(f"{task}/{robot} variation {variation}: {here} episodes{also}, expected {wanted}")
    seeds = Counter((record["task"], record["robot"], record["variation"], record["seed"]) for record in records)
    repeated = [(seed_key, count) for seed_key, count in seeds.items() if count > 1]
    if repeated:
        (task, robot, variation, seed), count = repeated[0]
        problems.append(
            f"{_plural(len(repeated), 'episode')} {'is' if len(repeated) == 1 else 'are'} in the dataset more than once "
            f"(same task, robot, variation and seed), e.g. {task}/{robot} variation {variation} seed {seed} ({count} times)"
        )


def _plural(number: int, noun: str) -> str:
    return f"{number} {noun}{'' if number == 1 else 's'}"


def _check_videos(root: Path, info: dict, episodes_meta, problems: list[str]) -> None:
    video_keys = [key for key, feature in info["features"].items() if isinstance(feature, dict) and feature.get("dtype") == "video"]
    if video_keys and "video_path" not in info:
        problems.append("meta/info.json has video features but no video_path: the videos cannot be found")
        return
    for key in video_keys:
        height, width = info["features"][key]["shape"][:2]
        chunk_column, file_column = f"videos/{key}/chunk_index", f"videos/{key}/file_index"
        expected_frames = episodes_meta.groupby([chunk_column, file_column])["length"].sum()
        for (chunk, file), frames in expected_frames.items():
            relative = info["video_path"].format(video_key=key, chunk_index=int(chunk), file_index=int(file))
            decoded, shape, error = _count_video_frames(root / relative)
            if error is not None:
                problems.append(f"{relative} does not decode ({error})")
            elif decoded != frames:
                problems.append(f"{relative} decodes to {decoded} frames, its episodes need {frames}")
            elif shape != (height, width):
                problems.append(f"{relative} frames are {shape[0]}x{shape[1]}, the schema says {height}x{width}")
    if unexpected := [key for key in video_keys if key != CAMERA_KEY]:
        problems.append(f"video features {listed(unexpected)} are not MOSAIC's (its only camera is {CAMERA_KEY})")


def _count_video_frames(path: Path) -> tuple[int, tuple[int, int] | None, str | None]:
    import av

    if not path.is_file():
        return 0, None, "file missing"
    count, shape = 0, None
    try:
        with av.open(str(path)) as container:
            for frame in container.decode(video=0):
                count += 1
                shape = (frame.height, frame.width)
    except Exception as error:  # av raises many error types for damaged streams
        return count, shape, f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''} after {count} frames"
    return count, shape, None
