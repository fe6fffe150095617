"""The one feature schema shared by every MOSAIC dataset (both robots, every task), and where datasets live.

One LeRobot v3 dataset per (task, robot), the same features for both robots (README, "Datasets"). Repo ids
are ``mosaic/<task>_<robot>`` for collected datasets and ``mosaic/all_<robot>`` for the merged multi-task ones;
the default place is LeRobot's ``HF_LEROBOT_HOME``.
"""

from __future__ import annotations

import json
from pathlib import Path

from mosaic_data.tasks.base import ACTION_DIM, CONTROL_FREQ_HZ, IMAGE_HEIGHT, IMAGE_WIDTH, STATE_DIM

REPO_NAMESPACE = "mosaic"
CAMERA_KEY = "observation.images.agentview"
FPS = CONTROL_FREQ_HZ
"""Frames per second of every dataset: one frame per 20 Hz control step."""

STATE_NAMES = ["x", "y", "z", "r00", "r01", "r02", "r10", "r11", "r12", "gripper_opening"]
ACTION_NAMES = ["x", "y", "z", "rx", "ry", "rz", "gripper"]


def dataset_features(image_height: int = IMAGE_HEIGHT, image_width: int = IMAGE_WIDTH) -> dict[str, dict]:
    """LeRobot feature dict of a MOSAIC dataset (the image size differs from 100x180 only in tests)."""
    return {
        CAMERA_KEY: {
            "dtype": "video",
            "shape": (image_height, image_width, 3),
            "names": ["height", "width", "channels"],
        },
        "observation.state": {"dtype": "float32", "shape": (STATE_DIM,), "names": list(STATE_NAMES)},
        "action": {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)},
        "variation": {"dtype": "int64", "shape": (1,), "names": None},
        "next.success": {"dtype": "bool", "shape": (1,), "names": None},
        "next.done": {"dtype": "bool", "shape": (1,), "names": None},
    }


def repo_id_for(task: str, robot: str) -> str:
    return f"{REPO_NAMESPACE}/{task}_{robot}"


def merged_repo_id_for(robot: str) -> str:
    return f"{REPO_NAMESPACE}/all_{robot}"


def default_output_dir() -> Path:
    """LeRobot's dataset home, read at call time so that ``HF_LEROBOT_HOME`` set in tests is honoured."""
    from lerobot.utils.constants import HF_LEROBOT_HOME

    return Path(HF_LEROBOT_HOME)


def dataset_root(output_dir: Path | None, repo_id: str) -> Path:
    """``<output_dir>/<repo_id>``, LeRobot's own layout (``LeRobotDataset(repo_id, root=...)`` takes this path)."""
    return (default_output_dir() if output_dir is None else Path(output_dir)) / repo_id


def is_lerobot_dataset(root: Path) -> bool:
    return (root / "meta" / "info.json").is_file()


def schema_mismatch(root: Path, image_height: int, image_width: int) -> str | None:
    """Why the dataset at ``root`` does not have the MOSAIC schema at this image size, or None if it does."""
    try:
        info = json.loads((root / "meta" / "info.json").read_text())
    except (OSError, json.JSONDecodeError) as error:
        return f"its meta/info.json cannot be read ({error})"
    features = info.get("features", {})
    for name, expected in dataset_features(image_height, image_width).items():
        found = features.get(name)
        if found is None:
            return f"it has no feature '{name}'"
        if found.get("dtype") != expected["dtype"] or list(found.get("shape", [])) != list(expected["shape"]):
            return (
                f"its feature '{name}' is {found.get('dtype')} {list(found.get('shape', []))}, "
                f"expected {expected['dtype']} {list(expected['shape'])}"
            )
    if info.get("fps") != FPS:
        return f"it runs at {info.get('fps')} fps, expected {FPS}"
    return None


def resolve_dataset(name_or_path: str | Path, output_dir: Path | None = None) -> Path:
    """Root of a local dataset given as a folder or as a repo id under ``output_dir`` (default LeRobot's home)."""
    path = Path(name_or_path).expanduser()
    if is_lerobot_dataset(path):
        return path
    candidate = dataset_root(output_dir, str(name_or_path))
    if is_lerobot_dataset(candidate):
        return candidate
    raise ValueError(
        f"no LeRobot dataset at {name_or_path!r} (looked for {path}/meta/info.json and {candidate}/meta/info.json): "
        "give a dataset folder, or a repo id such as mosaic/door_panda with --output-dir"
    )


def repo_id_of(root: Path) -> str:
    """The repo id a local dataset was made under (its sidecar says; else the last two folder names)."""
    from mosaic_data.collection.metadata import read_sidecar

    sidecar = read_sidecar(root) or {}
    return sidecar.get("repo_id") or f"{root.parent.name}/{root.name}"
