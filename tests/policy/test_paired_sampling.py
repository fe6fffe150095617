"""Pairing agent samples with demonstrator frames, read back from real LeRobot datasets."""

import numpy as np
import pytest
import torch
from tests.helpers.policy import IMAGE_KEY, read_variation_rank, variation_description, write_dataset

from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata
from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy
from mosaic_policy.common.paired_sampling import DemoDatasetError, PairedDemoSampler, demo_frame_indices


def test_demo_frames_are_first_last_and_one_per_middle_segment():
    assert demo_frame_indices(30, 4) == [0, 8, 22, 29]
    rng = np.random.default_rng(0)
    for _ in range(50):
        first, a, b, last = demo_frame_indices(30, 4, rng)
        assert first == 0 and last == 29 and 1 <= a <= 14 and 15 <= b <= 28
    assert len(demo_frame_indices(2, 4)) == 4  # short demos repeat frames


@pytest.mark.parametrize("threads", [0, 2])
def test_each_sample_gets_a_demo_of_its_variation_from_another_instance(door_datasets, threads):
    agent_root, demo_root = door_datasets
    agent_meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    sampler = PairedDemoSampler(
        "mosaic/door_sawyer", demo_root, IMAGE_KEY, 4, agent_meta=agent_meta, threads=threads, seed=threads
    )
    episode_tasks = [t[0] for t in agent_meta.episodes["tasks"]]
    agent_episodes = [0, 1, 2, 3, 4, 5, 6, 7, 0, 5]
    tasks = [episode_tasks[e] for e in agent_episodes]
    for _ in range(3):
        frames = sampler.sample(tasks, agent_episodes)
        assert frames.shape == (10, 4, 3, 32, 56) and frames.dtype == torch.uint8
        for i, episode in enumerate(agent_episodes):
            variation, rank = read_variation_rank(frames[i, 0])
            assert variation_description(variation) == tasks[i]
            assert rank != sampler.agent_rank[episode]  # another instance of the variation
            # the four frames are first, two middle ones, last: the moving square moves forward
            assert all(read_variation_rank(f) == (variation, rank) for f in frames[i])
    sampler.close()


def test_policy_built_for_training_pairs_batches_from_lerobot(door_datasets):
    agent_root, demo_root = door_datasets
    from tests.helpers.policy import small_config

    dataset = LeRobotDataset(
        "mosaic/door_panda", root=agent_root, delta_timestamps={IMAGE_KEY: [0, 0.05, 0.1], "action": [0, 0.05, 0.1], "observation.state": [0, 0.05, 0.1]}
    )
    config = small_config(demo_repo_id="mosaic/door_sawyer", demo_root=str(demo_root), demo_loader_threads=1)
    policy = MosaicPolicy(config, dataset_meta=dataset.meta).train()
    batch = next(iter(torch.utils.data.DataLoader(dataset, batch_size=4, shuffle=True)))
    batch[IMAGE_KEY] = batch[IMAGE_KEY].float()
    loss, info = policy.forward(batch)
    assert torch.isfinite(loss) and "demo_wait_s" in info


def test_missing_demo_dataset_is_a_clear_error(door_datasets, tmp_path):
    agent_root, _ = door_datasets
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    with pytest.raises(DemoDatasetError, match="not found"):
        PairedDemoSampler("mosaic/door_sawyer", tmp_path / "nowhere", IMAGE_KEY, 4, agent_meta=meta)
    from tests.helpers.policy import small_config

    with pytest.raises(ValueError, match="demo_repo_id"):
        MosaicPolicy(small_config(), dataset_meta=meta)


def test_demo_dataset_lacking_a_variation_is_a_clear_error(door_datasets, tmp_path):
    agent_root, _ = door_datasets
    partial = write_dataset(tmp_path / "partial", "mosaic/door_sawyer", [0, 1, 2], episodes_per_variation=1, length=4)
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    # a known selection is checked up front
    with pytest.raises(DemoDatasetError, match=r"no episode of 1 variation\(s\).*open door 1 right"):
        PairedDemoSampler("mosaic/door_sawyer", partial, IMAGE_KEY, 4, agent_meta=meta, agent_episodes=[0, 1, 2, 3])
    # inside lerobot-train the run's episodes are learnt from the batches: the first uncovered one fails
    sampler = PairedDemoSampler("mosaic/door_sawyer", partial, IMAGE_KEY, 4, agent_meta=meta, threads=0)
    tasks = [t[0] for t in meta.episodes["tasks"]]
    sampler.sample(tasks[:3], [0, 1, 2])  # variations 0-2 are covered
    with pytest.raises(DemoDatasetError, match="no episode of variation 'open door 1 right'; collect it"):
        sampler.sample(tasks[:4], [0, 1, 2, 3])


def test_demo_dataset_of_another_image_size_is_a_clear_error(door_datasets, tmp_path):
    agent_root, _ = door_datasets
    other = write_dataset(tmp_path / "big", "mosaic/door_sawyer", [0, 1, 2, 3], 1, 4, height=40, width=56)
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    with pytest.raises(DemoDatasetError, match="same image size"):
        PairedDemoSampler("mosaic/door_sawyer", other, IMAGE_KEY, 4, agent_meta=meta)


def test_a_fraction_of_the_agent_episodes_restricts_the_demonstrator_to_the_same_instances(tmp_path):
    """The paper's 25/50/75% runs: both robots see the same instances (ranks within each variation)."""
    agent_root = write_dataset(tmp_path / "agent", "mosaic/door_panda", [0, 1], episodes_per_variation=3, length=6)
    demo_root = write_dataset(tmp_path / "demo", "mosaic/door_sawyer", [0, 1], episodes_per_variation=3, length=6)
    agent_meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    ranks = dict(zip(range(6), [0, 0, 1, 1, 2, 2]))  # episodes alternate variations 0, 1 per rank
    selected = [0, 1, 2, 3]  # instances (ranks) 0 and 1 of both variations: two thirds of the data
    sampler = PairedDemoSampler(
        "mosaic/door_sawyer", demo_root, IMAGE_KEY, 4, agent_meta=agent_meta, agent_episodes=selected, threads=0
    )
    assert set(sampler.agent_rank) == set(selected)
    assert {rank for episodes in sampler.episodes_by_task.values() for _, rank in episodes} == {0, 1}
    tasks = [t[0] for t in agent_meta.episodes["tasks"]]
    for _ in range(5):
        frames = sampler.sample([tasks[e] for e in selected], selected)
        for i, episode in enumerate(selected):
            _, rank = read_variation_rank(frames[i, 0])
            assert rank in (0, 1) and rank != ranks[episode]
    with pytest.raises(DemoDatasetError, match="outside"):
        PairedDemoSampler("mosaic/door_sawyer", demo_root, IMAGE_KEY, 4, agent_meta=agent_meta, agent_episodes=[9], threads=0)


@pytest.mark.parametrize("damage", ["overwritten", "short"])
def test_a_damaged_demonstrator_video_names_its_file_in_training(tmp_path, damage):
    """torchcodec says "Could not push packet to decoder" (or LeRobot a tolerance assertion for lost frames) with no
    path: the training run must name the file and the fix."""
    from tests.helpers.video_damage import drop_last_frames, overwrite_middle

    agent = write_dataset(tmp_path / "door_panda", "mosaic/door_panda", [0, 1])
    demo = write_dataset(tmp_path / "door_sawyer", "mosaic/door_sawyer", [0, 1])
    videos = sorted((demo / "videos").rglob("*.mp4"))
    assert len(videos) == 1
    overwrite_middle(videos[0]) if damage == "overwritten" else drop_last_frames(videos[0], 6)
    agent_meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent)
    sampler = PairedDemoSampler("mosaic/door_sawyer", demo, IMAGE_KEY, 4, agent_meta=agent_meta, threads=0, seed=0)
    tasks = [t[0] for t in agent_meta.episodes["tasks"]]
    with pytest.raises(DemoDatasetError) as caught:
        for _ in range(20):  # every episode's last frame is drawn: the last episode's lie in the damaged part
            sampler.sample(tasks, list(range(len(tasks))))
    message = str(caught.value)
    assert str(videos[0]) in message and f"mosaic-data validate {demo}" in message and "\n" not in message
    sampler.close()


def test_inside_lerobot_train_the_demonstrator_side_follows_the_episodes_the_run_trains_on(tmp_path):
    """lerobot-train does not tell a policy its --dataset.episodes: the sampler learns them from the batches and
    never pairs a sample with an instance the run does not train on."""
    agent_root = write_dataset(tmp_path / "agent", "mosaic/door_panda", [0, 1], episodes_per_variation=3, length=6)
    demo_root = write_dataset(tmp_path / "demo", "mosaic/door_sawyer", [0, 1], episodes_per_variation=3, length=6)
    agent_meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    sampler = PairedDemoSampler("mosaic/door_sawyer", demo_root, IMAGE_KEY, 4, agent_meta=agent_meta, threads=0)
    tasks = [t[0] for t in agent_meta.episodes["tasks"]]
    trained_on = [0, 1, 2, 3]  # ranks 0 and 1 of both variations, as --dataset.episodes=[0,1,2,3] would give
    seen = set()
    for _ in range(6):
        frames = sampler.sample([tasks[e] for e in trained_on], trained_on)
        seen |= {read_variation_rank(frames[i, 0])[1] for i in range(len(trained_on))}
    assert seen == {0, 1}  # rank 2 (episodes 4, 5) is never shown
