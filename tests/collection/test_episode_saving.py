"""LeRobot's writer skips its row-by-row image-embedding pass on our video-only datasets, and writes the same files;
the streaming video encoder of a collection shard keeps every frame."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import torch
from lerobot.datasets import dataset_writer
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from mosaic_data.collection.episode_saving import skip_needless_image_embedding
from mosaic_data.collection.schema import FPS, dataset_features


def _episode_frame(features, rng, step: int, length: int) -> dict:
    """One frame of fixed pseudo-random content for every feature."""
    return {
        key: rng.integers(0, 256, spec["shape"], dtype=np.uint8) if spec["dtype"] in ("video", "image")
        else rng.standard_normal(spec["shape"]).astype(spec["dtype"]) if spec["dtype"] == "float32"
        else np.array([step == length - 1], dtype=bool) if spec["dtype"] == "bool"
        else np.array([1], dtype=np.int64)
        for key, spec in features.items()
    }


def write_episodes(root, features, image_key=None) -> None:
    """Two small episodes of fixed pseudo-random content through LeRobot's real writer."""
    rng = np.random.default_rng(0)
    dataset = LeRobotDataset.create("mosaic/saving_test", fps=FPS, features=features, root=root, robot_type="panda",
                                    use_videos=True)
    for length in (5, 7):
        for step in range(length):
            dataset.add_frame(_episode_frame(features, rng, step, length) | {"task": "open the door"})
        dataset.save_episode()
    dataset.finalize()


def parquet_bytes(root) -> dict[str, bytes]:
    return {str(path.relative_to(root)): path.read_bytes() for path in sorted(root.rglob("*.parquet"))}


def test_video_only_episodes_skip_the_embedding_pass_and_write_the_same_parquet(tmp_path, monkeypatch):
    original = dataset_writer.embed_images
    features = dataset_features(56, 96)
    write_episodes(tmp_path / "lerobot_as_is", features)

    calls = []
    monkeypatch.setattr(dataset_writer, "embed_images", lambda dataset: calls.append(1) or original(dataset))
    skip_needless_image_embedding()
    skip_needless_image_embedding()  # idempotent: one wrapper
    write_episodes(tmp_path / "skipping", features)
    assert calls == [], "the embedding pass still ran on a dataset without image columns"

    before, after = parquet_bytes(tmp_path / "lerobot_as_is"), parquet_bytes(tmp_path / "skipping")
    assert set(before) == set(after) and any(name.startswith("data/") for name in before)
    for name in before:
        if not name.startswith("data/"):
            assert before[name] == after[name], f"{name} differs"
            continue
        # Same table; the schema's "huggingface" metadata lacks only the cache fingerprint that datasets' map
        # leaves behind (nothing reads it back: loading makes a fingerprint of its own).
        as_is, skipping = (pq.read_table(tmp_path / folder / name) for folder in ("lerobot_as_is", "skipping"))
        assert as_is.equals(skipping) and as_is.schema.equals(skipping.schema), f"{name}: the data differ"
        as_is_meta, skipping_meta = (json.loads(t.schema.metadata[b"huggingface"]) for t in (as_is, skipping))
        assert {k: v for k, v in as_is_meta.items() if k != "fingerprint"} == skipping_meta
    loaded = [LeRobotDataset("mosaic/saving_test", root=tmp_path / folder) for folder in ("lerobot_as_is", "skipping")]
    assert len(loaded[0]) == len(loaded[1]) == 12
    for index in (0, 6, 11):
        first, second = loaded[0][index], loaded[1][index]
        assert all(torch.equal(first[key], second[key]) for key in first if isinstance(first[key], torch.Tensor))


def test_datasets_with_image_columns_still_embed(tmp_path, monkeypatch):
    original = dataset_writer.embed_images
    calls = []
    monkeypatch.setattr(dataset_writer, "embed_images", lambda dataset: calls.append(1) or original(dataset))
    skip_needless_image_embedding()
    features = dataset_features(56, 96)
    features["observation.images.agentview"]["dtype"] = "image"
    write_episodes(tmp_path / "images", features)
    assert calls == [1, 1], "LeRobot's embedding pass must still run when a column holds images"
    loaded = LeRobotDataset("mosaic/saving_test", root=tmp_path / "images")
    assert tuple(loaded[0]["observation.images.agentview"].shape) == (3, 56, 96)


def test_a_late_video_encoder_loses_no_frame(tmp_path, monkeypatch):
    """LeRobot's streaming encoder thread, held back for a second before it takes its first frame (what a loaded
    machine does to it), while a whole episode's frames arrive: every frame still reaches the video. (A camera
    encoder's queue of 30 frames drops each further frame it cannot take within 0.1 s.)"""
    import time

    import av
    from lerobot.datasets import video_utils

    from mosaic_data.collection.worker import create_shard_dataset

    run = video_utils._CameraEncoderThread.run

    def late_run(thread) -> None:
        time.sleep(1.0)
        run(thread)

    monkeypatch.setattr(video_utils._CameraEncoderThread, "run", late_run)
    height, width, length = 32, 56, 60
    dataset = create_shard_dataset("mosaic/door_panda", tmp_path / "shard", "panda", height, width, horizon=length)
    features = dataset_features(height, width)
    rng = np.random.default_rng(0)
    for step in range(length):
        dataset.add_frame(_episode_frame(features, rng, step, length) | {"task": "open the door"})
    dataset.save_episode()
    dataset.finalize()
    (video,) = (tmp_path / "shard" / "videos").rglob("*.mp4")
    with av.open(str(video)) as container:
        assert sum(1 for _ in container.decode(video=0)) == length
