"""``mosaic-data push``: LeRobot's ``push_to_hub`` with a dataset card that says what is inside and how it was made.

The sidecar is read matched to the dataset's current episodes (datasets edited with ``lerobot-edit-dataset``
included) and, when the edit left it stale or only in LeRobot's backup, rewritten in place before the upload, so
that the hub gets the records of exactly the episodes it gets. The first network call comes before that write:
offline (``HF_HUB_OFFLINE=1``) or without a network, push stops with one line and changes nothing.
``--dry-run`` writes the card to ``<dataset>/README.md`` (where the hub shows it) and uploads nothing.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from mosaic_data.atomic_files import write_bytes_atomically
from mosaic_data.collection.metadata import read_aligned_sidecar, sidecar_path, write_sidecar
from mosaic_data.collection.schema import CAMERA_KEY, check_repo_id

CARD_TAGS = ["mosaic", "one-shot-imitation", "robosuite", "simulation"]
PAPER = "Towards More Generalizable One-shot Visual Imitation Learning (MOSAIC), Zhao et al., ICRA 2022"


def dataset_description(sidecar: dict, repo_id: str, total_episodes: int | None = None, total_frames: int | None = None) -> str:
    """Markdown for the card's description: tasks, variations, robots, counts, provenance, how to load it.

    ``total_episodes``/``total_frames``: LeRobot's counts, which include episodes without a sidecar record.
    """
    counts = Counter((r["task"], r["robot"], r["variation"]) for r in sidecar["episodes"])
    robots = sidecar["robots"]
    episodes = len(sidecar["episodes"]) if total_episodes is None else total_episodes
    frames = sum(r["length"] for r in sidecar["episodes"]) if total_frames is None else total_frames
    lines = [
        f"Simulated expert demonstrations of the MOSAIC task suite for the {' and '.join(robots)} "
        f"({'agent' if robots == ['panda'] else 'demonstrator' if robots == ['sawyer'] else 'both roles'}), "
        f"{episodes} successful episodes, {frames} frames "
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
    ]
    noises = [source["settings"].get("action_noise") for source in sidecar["sources"]]
    stds = sorted({f"{noise['position_std_m']} m, {noise['rotation_std_rad']} rad" for noise in noises if isinstance(noise, dict)})
    if stds:
        lines += [
            f"Collected with DART-style noise injection (`--action-noise`, std {'; '.join(stds)}"
            + ("" if all(isinstance(noise, dict) for noise in noises) else ", in some of its sources")
            + "): the simulator executed each expert action with Gaussian noise on its target pose while `action` holds "
            "the expert's clean action, so episodes show the expert correcting small perturbations (an episode's noise "
            "follows from its seed: `action_noise` in the collection settings).",
            "",
        ]
    lines += [
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


@dataclass
class PushResult:
    """What ``push`` did (one line for the user) and what it should know (the sidecar's match, a rewrite)."""

    message: str
    warnings: list[str] = field(default_factory=list)


def push_dataset(root: Path, repo_id: str, private: bool = False, push_videos: bool = True, dry_run: bool = False) -> PushResult:
    """Upload the dataset at ``root`` (sidecar included) to ``repo_id`` with its card; ``dry_run`` only writes the
    card to ``<root>/README.md``. Bad input, no network or offline mode: ValueError with one line."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    check_repo_id(repo_id, "--repo-id")
    root = Path(root)
    aligned = read_aligned_sidecar(root)  # one-line error when there is no usable sidecar
    sidecar = aligned.sidecar
    dataset = LeRobotDataset(repo_id, root=root)
    card_options = {
        "tags": CARD_TAGS + list(sidecar["tasks"]) + sidecar["robots"],
        "dataset_description": dataset_description(sidecar, repo_id, dataset.meta.total_episodes, dataset.meta.total_frames),
        "paper": PAPER,
    }
    url = f"https://huggingface.co/datasets/{repo_id}"
    if dry_run:
        return _dry_run(dataset, aligned, card_options, root, url, private, push_videos)
    warnings = aligned.warnings(root, include_backup=False)
    with _hub_errors():  # the first call that needs the hub, before anything here is written
        from huggingface_hub import HfApi

        HfApi().create_repo(repo_id=repo_id, private=private, repo_type="dataset", exist_ok=True)
    if aligned.changed:  # the hub gets the records of exactly the episodes it gets
        write_sidecar(root, sidecar)
        removed = len(sidecar.get("removed_episodes", []))
        source = f" from LeRobot's backup {aligned.path}" if aligned.from_backup else ""
        warnings.append(
            f"wrote {sidecar_path(root)}{source} for the {aligned.total_episodes} episodes the dataset holds now"
            + (f" (the records of {removed} removed episodes are kept under removed_episodes)" if removed else "")
        )
    with _hub_errors():
        dataset.push_to_hub(private=private, push_videos=push_videos, **card_options)
    return PushResult(f"pushed {root} to {url}", warnings)


def _dry_run(dataset, aligned, card_options: dict, root: Path, url: str, private: bool, push_videos: bool) -> PushResult:
    """Write the card LeRobot's ``push_to_hub`` would upload to ``<root>/README.md``; count what would go up."""
    from lerobot.datasets.utils import create_lerobot_dataset_card

    card = create_lerobot_dataset_card(dataset_info=dataset.meta.info, license="apache-2.0", repo_id=dataset.repo_id, **card_options)
    card_path = root / "README.md"
    write_bytes_atomically(card_path, str(card).encode("utf-8"))
    skipped = ("images", ".git", ".cache") + (() if push_videos else ("videos",))
    files = [
        path for path in root.rglob("*")
        if path.is_file() and path.relative_to(root).parts[0] not in skipped and path != card_path
    ]
    size_mb = sum(path.stat().st_size for path in files) / 1e6
    rewrite = "; meta/mosaic.json would first be rewritten for the episodes the dataset holds now" if aligned.changed else ""
    return PushResult(
        f"dry run, nothing uploaded: the dataset card is in {card_path}; {len(files)} files ({size_mb:.1f} MB) and "
        f"the card would go to {url} ({'private' if private else 'public'} repository){rewrite}",
        aligned.warnings(root),
    )


class _hub_errors:
    """Turn "cannot reach the hub" into one line saying why and what to do; other errors pass unchanged."""

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind, error, traceback) -> bool:
        import httpx
        from huggingface_hub.errors import HfHubHTTPError, OfflineModeIsEnabled

        dry_run = "or add --dry-run to write the dataset card locally and upload nothing"
        if isinstance(error, OfflineModeIsEnabled):
            raise ValueError(
                "cannot push: Hugging Face hub access is off (HF_HUB_OFFLINE=1, which scripts/setup.sh sets): run it "
                f"again with HF_HUB_OFFLINE=0 on a machine with network access (logged in: `hf auth login`), {dry_run}"
            ) from None
        reason = (str(error).strip().splitlines() or [type(error).__name__])[0] if error is not None else ""
        if isinstance(error, (httpx.TransportError, ConnectionError)):
            raise ValueError(
                f"cannot push: the Hugging Face hub cannot be reached ({reason}): check the network connection "
                f"(and proxy settings) and run the same command again, {dry_run}"
            ) from None
        status = getattr(getattr(error, "response", None), "status_code", None)
        if isinstance(error, HfHubHTTPError) and status in (401, 403):
            raise ValueError(
                f"cannot push: the Hugging Face hub refused the upload ({reason}): log in with `hf auth login` "
                f"(a token with write access to the repo id's namespace), {dry_run}"
            ) from None
        return False
