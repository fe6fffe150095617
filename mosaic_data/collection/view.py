"""``mosaic-data view``: one episode (or an agent/demonstrator pair) as a rerun recording with a blueprint.

Frames come from LeRobot's own reader, so what you see is what a policy trained on the dataset sees. With
``--pair``, a demonstrator episode of the same variation (same LeRobot task string) is logged beside the
agent's, both starting at time 0 on the shared ``time`` timeline.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mosaic_data.collection.metadata import read_sidecar
from mosaic_data.collection.schema import ACTION_NAMES, CAMERA_KEY, FPS, is_lerobot_dataset, repo_id_of

OTHER_ROBOT = {"panda": "sawyer", "sawyer": "panda"}


def view_episode(root: Path, episode: int, pair: bool = False, pair_root: Path | None = None, save: Path | None = None) -> str:
    """Log the episode (and its pair) to rerun; save an ``.rrd`` or open the viewer. Returns what was shown."""
    import rerun as rr

    sidecar = _sidecar(root)
    record = _episode_record(sidecar, episode, root)
    shown = [(record["robot"], root, record)]
    if pair:
        pair_root = pair_root or _sibling_of_other_robot(root, record["robot"])
        pair_sidecar = _sidecar(pair_root)
        partner = _same_variation_episode(pair_sidecar, record)
        if partner is None:
            raise ValueError(f"{pair_root} has no episode of {record['task']} variation {record['variation']} to pair with")
        shown.append((partner["robot"], pair_root, partner))
    recording = rr.RecordingStream("mosaic_dataset", recording_id=f"{repo_id_of(root)}/episode_{episode}")
    blueprint = _blueprint([role for role, _, _ in shown])
    if save is not None:
        save.parent.mkdir(parents=True, exist_ok=True)
        recording.save(str(save), default_blueprint=blueprint)
    else:
        recording.spawn(default_blueprint=blueprint)
    for role, dataset_root, episode_record in shown:
        _log_episode(recording, role, dataset_root, episode_record, sidecar_of=_sidecar(dataset_root))
    recording.flush()
    description = _description(sidecar, record)
    names = ", ".join(f"{role} episode {r['episode_index']}" for role, _, r in shown)
    target = f"saved to {save} (open with: rerun {save})" if save is not None else "sent to the rerun viewer"
    return f"{names} of '{description}' {target}"


def _sidecar(root: Path) -> dict:
    sidecar = read_sidecar(root) if is_lerobot_dataset(root) else None
    if sidecar is None:
        raise ValueError(f"{root} is not a dataset made by `mosaic-data collect` (no meta/mosaic.json)")
    return sidecar


def _episode_record(sidecar: dict, episode: int, root: Path) -> dict:
    episodes = sidecar["episodes"]
    if not 0 <= episode < len(episodes):
        raise ValueError(f"--episode {episode} is out of range: {root} has episodes 0..{len(episodes) - 1}")
    return episodes[episode]


def _sibling_of_other_robot(root: Path, robot: str) -> Path:
    suffix = f"_{robot}"
    if not root.name.endswith(suffix):
        raise ValueError(f"cannot guess the other robot's dataset for {root}: give it with --pair-with")
    sibling = root.with_name(root.name[: -len(suffix)] + f"_{OTHER_ROBOT[robot]}")
    if not is_lerobot_dataset(sibling):
        raise ValueError(f"--pair needs the {OTHER_ROBOT[robot]} dataset {sibling}: collect it, or give another with --pair-with")
    return sibling


def _same_variation_episode(sidecar: dict, record: dict) -> dict | None:
    """The other robot's episode of the same variation, same slot if there is one (else the first)."""
    candidates = [r for r in sidecar["episodes"] if r["task"] == record["task"] and r["variation"] == record["variation"]]
    same_slot = [r for r in candidates if r["slot"] == record["slot"]]
    return (same_slot or candidates or [None])[0]


def _description(sidecar: dict, record: dict) -> str:
    return sidecar["tasks"][record["task"]]["variations"][record["variation"]]["description"]


def _blueprint(roles: list[str]):
    import rerun.blueprint as rrb

    columns = [
        rrb.Vertical(
            rrb.Spatial2DView(origin=f"/{role}/camera", name=f"{role}: agentview"),
            rrb.TimeSeriesView(origin=f"/{role}/action", name=f"{role}: action (target pose, gripper)"),
            rrb.TimeSeriesView(origin=f"/{role}/state", name=f"{role}: state"),
            rrb.TimeSeriesView(origin=f"/{role}/success", name=f"{role}: success"),
            row_shares=[3, 2, 2, 1],
        )
        for role in roles
    ]
    return rrb.Blueprint(
        rrb.Horizontal(*columns, rrb.TextDocumentView(origin="/description", name="episode")),
        rrb.TimePanel(timeline="time"),
        collapse_panels=True,
    )


def _log_episode(recording, role: str, root: Path, record: dict, sidecar_of: dict) -> None:
    import rerun as rr
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset(repo_id_of(root), root=root, episodes=[record["episode_index"]])
    recording.log(
        f"/description/{role}",
        rr.TextDocument(
            f"{role}: {record['task']} variation {record['variation']}: {_description(sidecar_of, record)}\n"
            f"episode {record['episode_index']}, seed {record['seed']}, {record['length']} frames, "
            f"{record['attempts'] - 1} expert retries"
        ),
        static=True,
    )
    for name in ACTION_NAMES:
        recording.log(f"/{role}/action/{name}", rr.SeriesLines(names=name), static=True)
    for step in range(len(dataset)):
        frame = dataset[step]
        recording.set_time("frame", sequence=step)
        recording.set_time("time", duration=step / FPS)
        image = (frame[CAMERA_KEY].permute(1, 2, 0).numpy() * 255.0).round().astype(np.uint8)
        recording.log(f"/{role}/camera", rr.Image(image))
        for name, value in zip(ACTION_NAMES, frame["action"].tolist()):
            recording.log(f"/{role}/action/{name}", rr.Scalars(value))
        state = frame["observation.state"].tolist()
        for name, value in zip(["x", "y", "z"], state[:3]):
            recording.log(f"/{role}/state/{name}", rr.Scalars(value))
        recording.log(f"/{role}/state/gripper_opening", rr.Scalars(state[-1]))
        recording.log(f"/{role}/success", rr.Scalars(float(bool(frame["next.success"]))))
