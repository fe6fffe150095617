"""``mosaic-data push``: LeRobot's ``push_to_hub`` with a dataset card that says what is inside and how it was made."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from mosaic_data.collection.metadata import read_sidecar
from mosaic_data.collection.schema import CAMERA_KEY

CARD_TAGS = ["mosaic", "one-shot-imitation", "robosuite", "simulation"]
PAPER = "Towards More Generalizable One-shot Visual Imitation Learning (MOSAIC), Zhao et al., ICRA 2022"


def dataset_description(sidecar: dict, repo_id: str) -> str:
    """Markdown for the card's description: tasks, variations, robots, counts, provenance, how to load it."""
    counts = Counter((r["task"], r["robot"], r["variation"]) for r in sidecar["episodes"])
    robots = sidecar["robots"]
    lines = [
        f"Simulated expert demonstrations of the MOSAIC task suite for the {' and '.join(robots)} "
        f"({'agent' if robots == ['panda'] else 'demonstrator' if robots == ['sawyer'] else 'both roles'}), "
        f"{len(sidecar['episodes'])} successful episodes, {sum(r['length'] for r in sidecar['episodes'])} frames "
        f"at {sidecar['sources'][0]['settings']['fps']} fps.",
        "",
        "The LeRobot task string of every frame is its variation's description; it is unique across the suite and "
        "pairs demonstrator and agent episodes of the same variation. Per frame: `" + CAMERA_KEY + "` (video), "
        "`observation.state` (end-effector position, rotation 6D, gripper opening), `action` (absolute world-frame "
        "end-effector target: xyz, rotation vector of the turn from a gripper-down reference, gripper -1 open / +1 closed), `variation`, `next.success`, `next.done`.",
        "",
        "### Tasks and variations",
        "",
        "| task | variation | description | " + " | ".join(f"{robot} episodes" for robot in robots) + " |",
        "|---|---|---|" + "---|" * len(robots),
    ]
    for task, table in sidecar["tasks"].items():
        for variation in table["variations"]:
            row_counts = [counts.get((task, robot, variation["index"]), 0) for robot in robots]
            if any(row_counts):
                lines.append(
                    f"| {task} | {variation['index']} | {variation['description']} | " + " | ".join(map(str, row_counts)) + " |"
                )
    retries = sum(r["attempts"] - 1 for r in sidecar["episodes"])
    software = ", ".join(f"{name} {version}" for name, version in sidecar["software"].items())
    lines += [
        "",
        "### How it was made",
        "",
        "Scripted experts (state machines over ground-truth simulator poses) in robosuite/MuJoCo scenes built from "
        "Meta-World assets, run by `mosaic-data collect`; only successful rollouts are kept "
        f"({retries} failed expert attempts were retried with fresh seeds). Every episode's instance seed, variation "
        "and retries are in `meta/mosaic.json`, with the full variation tables and collection settings: "
        "`make_task_env(task, variation, robot).reset_to_seed(seed)` and the task's expert regenerate it.",
        "",
        f"Software: {software}.",
        "",
        "### Load it",
        "",
        "```python",
        "from lerobot.datasets.lerobot_dataset import LeRobotDataset",
        "",
        f'dataset = LeRobotDataset("{repo_id}")',
        "```",
    ]
    return "\n".join(lines)


def push_dataset(root: Path, repo_id: str, private: bool = False, push_videos: bool = True) -> str:
    """Upload the dataset at ``root`` (sidecar included) to ``repo_id`` with its card; returns the dataset's URL."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if repo_id.count("/") != 1 or not all(repo_id.split("/")):
        raise ValueError(f"--repo-id must look like user/name, got {repo_id!r}")
    sidecar = read_sidecar(root)
    if sidecar is None:
        raise ValueError(f"{root} has no meta/mosaic.json: push datasets made by `mosaic-data collect` (or use LeRobot's own push_to_hub)")
    dataset = LeRobotDataset(repo_id, root=root)
    tasks = list(sidecar["tasks"])
    dataset.push_to_hub(
        tags=CARD_TAGS + tasks + sidecar["robots"],
        private=private,
        push_videos=push_videos,
        dataset_description=dataset_description(sidecar, repo_id),
        paper=PAPER,
    )
    return f"https://huggingface.co/datasets/{repo_id}"
