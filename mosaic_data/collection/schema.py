"""The one feature schema shared by every MOSAIC dataset (both robots, every task), and where datasets live.

One LeRobot v3 dataset per (task, robot), the same features for both robots (README, "Datasets"). Repo ids
are ``mosaic/<task>_<robot>`` for collected datasets and ``mosaic/all_<robot>`` for the merged multi-task ones;
the default place is LeRobot's ``HF_LEROBOT_HOME``.
"""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

from mosaic_data.constants import (  # noqa: F401  (CAMERA_KEY and FPS are imported from here too)
    ACTION_DIM,
    ACTION_KEY,
    CAMERA_KEY,
    FPS,
    IMAGE_HEIGHT,
    IMAGE_WIDTH,
    STATE_DIM,
    STATE_KEY,
    STATE_NAMES,
)

REPO_NAMESPACE = "mosaic"

ACTION_NAMES = ["x", "y", "z", "rx", "ry", "rz", "gripper"]


def dataset_features(image_height: int = IMAGE_HEIGHT, image_width: int = IMAGE_WIDTH) -> dict[str, dict]:
    """LeRobot feature dict of a MOSAIC dataset (the image size differs from 100x180 only in tests)."""
    return {
        CAMERA_KEY: {
            "dtype": "video",
            "shape": (image_height, image_width, 3),
            "names": ["height", "width", "channels"],
        },
        STATE_KEY: {"dtype": "float32", "shape": (STATE_DIM,), "names": list(STATE_NAMES)},
        ACTION_KEY: {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)},
        "variation": {"dtype": "int64", "shape": (1,), "names": None},
        "next.success": {"dtype": "bool", "shape": (1,), "names": None},
        "next.done": {"dtype": "bool", "shape": (1,), "names": None},
    }


REPO_ID_PART = re.compile(r"[A-Za-z0-9_](?:[A-Za-z0-9._-]{0,94}[A-Za-z0-9_])?")
"""One half of a repo id: what the Hugging Face hub accepts (letters, digits, ``-``, ``_``, ``.``; not starting
or ending with ``.`` or ``-``), which also makes it a plain, visible folder name: never ``..``, never a path."""


def check_repo_id(repo_id: str, flag: str = "--repo-id") -> str:
    """Return ``repo_id`` if it is ``namespace/name`` with safe characters, else raise ValueError naming ``flag``.

    Every command that turns a repo id into a folder (``<output_dir>/<repo_id>``) or a hub repository calls this
    first: an empty id (an unset shell variable), a bare ``mosaic``, ``../x`` or ``/abs/path`` would otherwise
    point at the output folder itself, its namespace folder (holding other datasets) or outside it, and an
    ``--overwrite`` would replace that. ``flag`` is the option the user gave it with, for the message.
    """
    text = repo_id if isinstance(repo_id, str) else str(repo_id)
    parts = text.split("/")
    if len(parts) == 2 and all(REPO_ID_PART.fullmatch(part) for part in parts) and ".." not in text and "--" not in text:
        return text
    raise ValueError(
        f"{flag} {text!r} is not a repo id: give namespace/name such as mosaic/door_drawer_panda "
        "(letters, digits, '-', '_', '.' in each part; no '..', '--', leading or trailing '.' or '-')"
    )


def repo_id_for(task: str, robot: str) -> str:
    return f"{REPO_NAMESPACE}/{task}_{robot}"


def merged_repo_id_for(robot: str) -> str:
    return f"{REPO_NAMESPACE}/all_{robot}"


def default_output_dir() -> Path:
    """LeRobot's dataset home, read at call time so that ``HF_LEROBOT_HOME`` set in tests is honoured.

    Once LeRobot is loaded its own value counts (it reads the variable once, at import); until then the same rule
    (``$HF_LEROBOT_HOME``, else ``$HF_HOME/lerobot``) is applied here, because importing LeRobot for it costs
    seconds (torch) and a command checks its output folder before any heavy import.
    """
    lerobot_constants = sys.modules.get("lerobot.utils.constants")
    if lerobot_constants is not None:
        return Path(lerobot_constants.HF_LEROBOT_HOME)
    from huggingface_hub.constants import HF_HOME  # what LeRobot's default derives from; no torch

    return Path(os.getenv("HF_LEROBOT_HOME", Path(HF_HOME) / "lerobot")).expanduser()


def check_output_dir(output_dir: Path | None, namespace: str = REPO_NAMESPACE) -> None:
    """Raise a one-line ValueError unless datasets can be made in ``<output_dir>/<namespace>`` (LeRobot's home
    without ``output_dir``); missing folders are made later. Commands call it before any work: a file in the way
    would otherwise stop them only when the first dataset is written, seconds or minutes in, with a traceback."""
    target = (default_output_dir() if output_dir is None else Path(output_dir)).expanduser().absolute()
    fix = "choose another --output-dir" if output_dir is not None else "set HF_LEROBOT_HOME to a folder, or pass --output-dir"
    existing = target / namespace
    while not existing.exists() and existing != existing.parent:  # the folders still to make; the first one there decides
        existing = existing.parent
    if existing == target and not target.is_dir():
        raise ValueError(f"cannot write datasets under {target}: it is a file, not a folder ({fix})")
    if not existing.is_dir():
        raise ValueError(f"cannot write datasets under {target}: {existing} is a file, not a writable folder ({fix})")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"cannot write datasets under {target}: {existing} is not a writable folder ({fix})")


def dataset_root(output_dir: Path | None, repo_id: str, flag: str = "--repo-id") -> Path:
    """``<output_dir>/<repo_id>``, LeRobot's own layout (``LeRobotDataset(repo_id, root=...)`` takes this path).

    The repo id is checked (:func:`check_repo_id`) so that the result is always one dataset folder two levels
    below ``output_dir``: never the output folder, a namespace folder or a place outside it.
    """
    check_repo_id(repo_id, flag)
    return (default_output_dir() if output_dir is None else Path(output_dir)).expanduser() / repo_id


def is_lerobot_dataset(root: Path) -> bool:
    return (root / "meta" / "info.json").is_file()


def schema_mismatch(root: Path, image_height: int, image_width: int) -> str | None:
    """Why the dataset at ``root`` does not have the MOSAIC schema at this image size, or None if it does."""
    try:
        info = json.loads((root / "meta" / "info.json").read_text())
    except (OSError, json.JSONDecodeError) as error:
        return f"its meta/info.json cannot be read ({error})"
    mismatch = feature_mismatch(info.get("features") or {}, dataset_features(image_height, image_width))
    if mismatch is not None:
        return f"its {mismatch}"
    if info.get("fps") != FPS:
        return f"it runs at {info.get('fps')} fps, expected {FPS}"
    return None


def feature_mismatch(found: dict[str, dict], expected: dict[str, dict], extra_allowed: bool = True) -> str | None:
    """The first difference of a LeRobot feature dict from ``expected``, in full, or None.

    Says the feature, what it is and what it should be (``feature 'x' is video [48, 88, 3], expected video
    [56, 96, 3]``; ``feature 'x' is missing, expected float32 [7]``), never cut: this text ends up in one-line
    errors whose point is the expected shape. Extra features count only without ``extra_allowed``.
    """
    for name, want in expected.items():
        have = found.get(name)
        wanted = f"{want.get('dtype')} {_shape_text(want)}"
        if not isinstance(have, dict):
            return f"feature '{name}' is missing, expected {wanted}"
        if have.get("dtype") != want.get("dtype") or _shape_text(have) != _shape_text(want):
            return f"feature '{name}' is {have.get('dtype')} {_shape_text(have)}, expected {wanted}"
    if not extra_allowed:
        for name, have in found.items():
            if name not in expected:
                return f"feature '{name}' ({have.get('dtype')} {_shape_text(have)}) is not expected"
    return None


def _shape_text(feature: dict) -> str:
    shape = feature.get("shape")
    return "without a shape" if shape is None else str([int(n) for n in shape])


def resolve_dataset(name_or_path: str | Path, output_dir: Path | None = None, where_hint: str = "with --output-dir") -> Path:
    """Root of a local dataset given as a folder or as a repo id under ``output_dir`` (default LeRobot's home).

    ``where_hint`` ends the error's advice on repo ids: how the caller's command says where datasets live (the
    default is mosaic-data's flag; a command without ``--output-dir`` names its own way, e.g. HF_LEROBOT_HOME).
    """
    path = Path(name_or_path).expanduser()
    if is_lerobot_dataset(path):
        return path
    looked = [path]
    try:
        candidate = dataset_root(output_dir, str(name_or_path))
    except ValueError:  # not a repo id: only the folder reading applies
        candidate = None
    if candidate is not None:
        if is_lerobot_dataset(candidate):
            return candidate
        if candidate.absolute() != path.absolute():
            looked.append(candidate)
    places = " and ".join(f"{place}/meta/info.json" for place in looked)
    raise ValueError(
        f"no LeRobot dataset at {str(name_or_path)!r} (looked for {places}): "
        f"give a dataset folder, or a repo id such as mosaic/door_panda {where_hint}"
    )


def repo_id_of(root: Path) -> str:
    """The repo id a local dataset was made under (its sidecar says; else the last two folder names)."""
    from mosaic_data.collection.metadata import read_sidecar

    sidecar = read_sidecar(root) or {}
    return sidecar.get("repo_id") or f"{root.parent.name}/{root.name}"
