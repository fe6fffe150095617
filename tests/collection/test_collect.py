"""Collection into real LeRobot datasets: what LeRobot reads back, seeds that regenerate episodes, reruns."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from mosaic_data.collection.metadata import read_sidecar
from mosaic_data.collection.plan import episode_seed
from mosaic_data.collection.schema import CAMERA_KEY, dataset_features
from mosaic_data.tasks import get_task_class
from tests.helpers.collection import HEIGHT, TEST_IMAGE_SIZE, WIDTH


@pytest.mark.parametrize("robot", ["panda", "sawyer"])
def test_lerobot_reads_collected_dataset(door_output, robot):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = door_output / "mosaic" / f"door_{robot}"
    dataset = LeRobotDataset(f"mosaic/door_{robot}", root=root)
    expected = dataset_features(HEIGHT, WIDTH)
    for name, feature in expected.items():
        assert dataset.features[name]["dtype"] == feature["dtype"]
        assert tuple(dataset.features[name]["shape"]) == feature["shape"]
    assert dataset.meta.robot_type == robot
    descriptions = [v.description for v in get_task_class("door").variations]
    assert sorted(dataset.meta.tasks.index) == sorted(descriptions)
    assert dataset.num_episodes == 4
    variations = np.array([int(v) for v in dataset.hf_dataset["variation"]])
    episode_index = np.array([int(e) for e in dataset.hf_dataset["episode_index"]])
    assert sorted(set(zip(episode_index.tolist(), variations.tolist()))) == [(0, 0), (1, 1), (2, 2), (3, 3)]
    last = dataset[len(dataset) - 1]
    assert bool(last["next.done"]) and bool(last["next.success"])
    assert not bool(dataset[0]["next.done"]) and not bool(dataset[0]["next.success"])
    assert last["task"] == descriptions[3]


def test_sidecar_seeds_regenerate_episodes(door_output, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from mosaic_data.experts import make_expert
    from mosaic_data.tasks import make_task_env

    root = door_output / "mosaic" / "door_sawyer"
    sidecar = read_sidecar(root)
    assert sidecar["robots"] == ["sawyer"] and list(sidecar["tasks"]) == ["door"]
    assert [v["description"] for v in sidecar["tasks"]["door"]["variations"]] == [v.description for v in get_task_class("door").variations]
    assert sidecar["software"]["lerobot"] and sidecar["sources"][0]["settings"]["episodes_per_variation"] == 1
    record = sidecar["episodes"][2]
    assert record["seed"] == episode_seed(0, record["variation"], record["slot"], record["attempts"] - 1)
    assert len(record["failed_seeds"]) == record["attempts"] - 1

    dataset = LeRobotDataset("mosaic/door_sawyer", root=root, episodes=[record["episode_index"]])
    stored_first = (dataset[0][CAMERA_KEY].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    Image.fromarray(stored_first).save(tmp_path / "first_frame.png")  # for a person to look at
    env = make_task_env("door", record["variation"], "sawyer", image_height=HEIGHT, image_width=WIDTH)
    try:
        env.reset_to_seed(record["seed"])
        regenerated = env.render_agentview()
        expert = make_expert(env)
        actions = [expert.act() for _ in range(1)]
    finally:
        env.close()
    # AV1 is lossy: the same scene differs by a few grey levels, another instance by far more.
    assert np.abs(stored_first.astype(float) - regenerated.astype(float)).mean() < 6.0
    np.testing.assert_allclose(dataset[0]["action"].numpy(), actions[0], atol=1e-6)
    assert len(dataset) == record["length"]


def test_rerun_leaves_complete_dataset_alone_and_refuses_other_settings(door_output, capsys, cli):
    info = (door_output / "mosaic" / "door_panda" / "meta" / "info.json").stat().st_mtime_ns
    args = ["collect", "--task", "door", "--robot", "panda", "--episodes", "1", "--output-dir", str(door_output),
            "--image-size", TEST_IMAGE_SIZE, "--quiet"]
    assert cli(*args) == 0
    assert "complete, left alone" in capsys.readouterr().out
    assert (door_output / "mosaic" / "door_panda" / "meta" / "info.json").stat().st_mtime_ns == info
    assert cli(*args, "--seed", "7") == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "seed" in error and "--overwrite" in error
    assert not (door_output / "mosaic" / ".door_panda.collecting").exists()


def test_task_all_merges_the_suite_and_a_rerun_leaves_every_dataset_alone(tmp_path, monkeypatch, capsys, cli):
    """``--task all`` on a two-task suite (the whole suite takes minutes): per-task datasets, then the merged
    ``mosaic/all_panda`` that LeRobot reads with every variation; run again, everything is reported as left alone."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    import mosaic_data.tasks

    monkeypatch.setattr(mosaic_data.tasks, "TASK_NAMES", ("door", "press_button"))  # the suite's table of names
    arguments = ["collect", "--task", "all", "--robot", "panda", "--episodes", "1", "--workers", "2",
                 "--output-dir", str(tmp_path), "--image-size", TEST_IMAGE_SIZE, "--quiet"]
    assert cli(*arguments) == 0
    merged = LeRobotDataset("mosaic/all_panda", root=tmp_path / "mosaic" / "all_panda")
    descriptions = [v.description for task in ("door", "press_button") for v in get_task_class(task).variations]
    assert sorted(merged.meta.tasks.index) == sorted(descriptions)
    assert merged.num_episodes == len(descriptions)
    sidecar = read_sidecar(tmp_path / "mosaic" / "all_panda")
    assert [source["task"] for source in sidecar["sources"]] == ["door", "press_button"]
    assert cli("validate", str(tmp_path / "mosaic" / "all_panda")) == 0
    capsys.readouterr()
    assert cli(*arguments) == 0
    report = capsys.readouterr().out
    for repo_id in ("mosaic/door_panda", "mosaic/press_button_panda", "mosaic/all_panda"):
        assert f"{repo_id}: complete, left alone" in report


def test_a_failed_expert_attempt_leaves_no_frames_in_the_shard(tmp_path):
    """Steps are written while the expert acts; a failed attempt must vanish from the parquet and the video
    (LeRobot's clear_episode_buffer cancels its streaming encoding). The first attempt is made to fail by
    declaring its instance unsuccessful; the simulator, writer and encoder are the real ones."""
    import av
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from mosaic_data.collection.plan import CollectionSettings, ShardSpec
    from mosaic_data.collection.worker import EnvironmentCache, collect_shard

    settings = CollectionSettings(task="door", robot="panda", variations=(1,), episodes_per_variation=1, base_seed=0,
                                  image_height=HEIGHT, image_width=WIDTH)
    spec = ShardSpec(settings, variation=1, first_slot=0, end_slot=1, staging_dir=tmp_path / "staging")
    environments = EnvironmentCache()
    env = environments.get(settings, 1)
    first_attempt, real_check = episode_seed(0, 1, 0, 0), env.check_success
    env.check_success = lambda *args, **kwargs: env.instance_seed != first_attempt and real_check(*args, **kwargs)
    try:
        result = collect_shard(spec, environments)
        assert result.episodes[0]["attempts"] == 2 and result.episodes[0]["failed_seeds"] == [first_attempt]
        env.check_success = real_check
        env.reset_to_seed(episode_seed(0, 1, 0, 1))
        regenerated = env.render_agentview()
    finally:
        environments.close()
    dataset = LeRobotDataset("mosaic/door_panda", root=spec.root)
    assert len(dataset) == result.episodes[0]["length"] == result.frames
    videos = list((spec.root / "videos").rglob("*.mp4"))
    assert len(videos) == 1
    with av.open(str(videos[0])) as container:
        assert sum(1 for _ in container.decode(video=0)) == len(dataset)
    stored_first = (dataset[0][CAMERA_KEY].permute(1, 2, 0).numpy() * 255).round()
    assert np.abs(stored_first - regenerated.astype(float)).mean() < 6.0  # the successful attempt's first frame
