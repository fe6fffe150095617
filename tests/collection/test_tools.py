"""validate, view (rerun), push (network intercepted) and merge on the shared tiny collection."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from mosaic_data.collection.validate import validate_dataset



def test_validate_accepts_collected_dataset(door_output, capsys, cli):
    assert cli("validate", str(door_output / "mosaic" / "door_panda")) == 0
    assert "OK (4 episodes" in capsys.readouterr().out
    assert cli("validate", "mosaic/door_sawyer", "--output-dir", str(door_output)) == 0


@pytest.fixture
def damaged_copy(door_output, tmp_path):
    copy = tmp_path / "door_panda"
    shutil.copytree(door_output / "mosaic" / "door_panda", copy)
    return copy


def test_validate_catches_corrupted_video(damaged_copy, capsys, cli):
    video = next((damaged_copy / "videos").rglob("*.mp4"))
    content = video.read_bytes()
    video.write_bytes(content[: len(content) // 2])
    summary, problems = validate_dataset(damaged_copy)
    assert any(video.name in problem for problem in problems), problems
    assert cli("validate", str(damaged_copy)) == 1
    assert video.name in capsys.readouterr().err


def test_validate_catches_truncated_parquet(damaged_copy):
    data = next((damaged_copy / "data").rglob("*.parquet"))
    data.write_bytes(data.read_bytes()[:-200])
    _, problems = validate_dataset(damaged_copy)
    assert any("cannot be read" in problem and data.name in problem for problem in problems), problems


def test_validate_catches_missing_episode_metadata(damaged_copy):
    from mosaic_data.collection.metadata import read_sidecar, write_sidecar

    sidecar = read_sidecar(damaged_copy)
    sidecar["episodes"] = sidecar["episodes"][:-1]
    write_sidecar(damaged_copy, sidecar)
    warnings: list[str] = []
    _, problems = validate_dataset(damaged_copy, warnings)
    # the episode is in the data (its task string gives its variation): a warning, as after a LeRobot edit
    assert problems == [] and any("1 episode has no sidecar record" in warning for warning in warnings), (problems, warnings)


def test_view_pair_writes_rerun_recording_with_blueprint(door_output, tmp_path, capsys, cli):
    import rerun as rr

    rrd = tmp_path / "pair.rrd"
    assert cli("view", "mosaic/door_panda", "--output-dir", str(door_output), "--episode", "1", "--pair", "--save", str(rrd)) == 0
    assert "sawyer episode 1" in capsys.readouterr().out
    reader = rr.experimental.RrdReader(rrd)
    assert len(reader.recordings()) == 1 and len(reader.blueprints()) == 1
    entities = set(reader.store().schema().entity_paths())
    for role in ("panda", "sawyer"):
        assert {f"/{role}/camera", f"/{role}/action/x", f"/{role}/state/gripper_opening", f"/{role}/success"} <= entities


def test_push_uploads_dataset_sidecar_and_card(door_output, monkeypatch, capsys, cli):
    import huggingface_hub
    import huggingface_hub._upload_pipeline as upload_pipeline
    from huggingface_hub import HfApi

    # Only the calls that would reach the hub are replaced: repo creation, the (xet) folder upload pipeline,
    # commits (the dataset card) and tags. Everything LeRobot and huggingface_hub do before them runs for real.
    calls: dict[str, list] = {"create_repo": [], "commits": [], "tags": []}

    def pipelined_upload(api, *, repo_id, add_operations, **kwargs):
        calls["commits"].append((repo_id, list(add_operations)))

    def create_repo(self, repo_id, **kwargs):
        calls["create_repo"].append((repo_id, kwargs))

    def create_commit(self, repo_id, operations, **kwargs):
        operations = list(operations)
        for operation in operations:  # the card is a temporary file, gone once the upload returns
            if isinstance(operation.path_or_fileobj, (str, Path)):
                operation.path_or_fileobj = Path(operation.path_or_fileobj).read_bytes()
        calls["commits"].append((repo_id, operations))

    monkeypatch.setattr(HfApi, "create_repo", create_repo)
    monkeypatch.setattr(HfApi, "create_commit", create_commit)
    monkeypatch.setattr(upload_pipeline, "pipelined_upload", pipelined_upload)
    monkeypatch.setattr(huggingface_hub.repocard.RepoCard, "validate", lambda self, repo_type=None: None)  # POST /api/validate-yaml
    monkeypatch.setattr(HfApi, "create_tag", lambda self, repo_id, **kw: calls["tags"].append(kw["tag"]))
    monkeypatch.setattr(HfApi, "delete_tag", lambda self, repo_id, **kw: None)
    assert cli("push", "mosaic/door_panda", "--output-dir", str(door_output), "--repo-id", "someone/door_panda", "--private") == 0
    assert calls["create_repo"][0][0] == "someone/door_panda" and calls["create_repo"][0][1]["private"] is True
    uploaded = {op.path_in_repo: op for _, operations in calls["commits"] for op in operations}
    assert "meta/mosaic.json" in uploaded and "meta/info.json" in uploaded
    assert any(path.startswith("videos/") and path.endswith(".mp4") for path in uploaded)
    assert any(path.startswith("data/") and path.endswith(".parquet") for path in uploaded)
    card = uploaded["README.md"].path_or_fileobj
    card = card.decode() if isinstance(card, bytes) else card.read().decode()
    assert "push the left door open, away from the robot" in card and "LeRobotDataset(\"someone/door_panda\")" in card
    assert "panda episodes" in card and "mosaic" in card


def test_merge_refuses_mixing_robots(door_output, capsys, cli):
    status = cli("merge", "mosaic/door_panda", "mosaic/door_sawyer", "--repo-id", "mosaic/mixed",
                     "--output-dir", str(door_output))
    assert status == 2
    assert "different robots" in capsys.readouterr().err
    assert not (door_output / "mosaic" / "mixed").exists()


def test_validate_reports_an_action_jump_that_no_motion_explains():
    """A rotation flipping sign near pi (as a world axis-angle chart of a top-down grasp does) is a problem; a smooth
    expert motion is not."""
    import numpy as np

    from mosaic_data.collection.validate import _check_action_jumps

    smooth = np.zeros((20, 7))
    smooth[:, 0] = np.linspace(0.0, 0.2, 20)  # 1 cm per step
    smooth[:, 5] = np.linspace(0.0, 1.0, 20)  # 0.05 rad per step
    smooth[10:, 6] = 1.0  # the gripper closes in one step: allowed
    problems: list[str] = []
    _check_action_jumps(smooth, "episode 0", problems)
    assert problems == []
    flipped = smooth.copy()
    flipped[:, 3] = 3.1
    flipped[12:, 3] = -3.1  # +pi -> -pi: the same orientation, a 6.2 rad jump of the numbers
    _check_action_jumps(flipped, "episode 3", problems)
    assert len(problems) == 1 and problems[0].startswith("episode 3: action rx jumps by 6.200 rad")


def test_validate_warns_on_a_hold_longer_than_a_policy_step(damaged_copy, capsys, cli):
    """The collected door episodes keep moving; the same episode with its action held for 8 steps mid-episode
    (a stop a policy seeing one frame cannot tell from an arrival) gets one warning line naming it."""
    import numpy as np
    import pandas as pd

    assert cli("validate", str(damaged_copy)) == 0
    assert "hold the hand still" not in capsys.readouterr().out
    data_file = next((damaged_copy / "data").rglob("*.parquet"))
    frames = pd.read_parquet(data_file)
    first = frames.index[frames["episode_index"] == frames["episode_index"].iloc[0]]
    held = np.asarray(frames.loc[first[10], "action"])
    for row in first[11:19]:
        frames.at[row, "action"] = held
    frames.to_parquet(data_file)
    warnings: list[str] = []
    validate_dataset(damaged_copy, warnings)
    hold_lines = [line for line in warnings if "hold the hand still" in line]
    assert len(hold_lines) == 1 and "longest: 8 steps in episode 0" in hold_lines[0], warnings
