"""`hand_relative_targets`: position targets predicted as offsets from the hand, absolute everywhere outside the
policy. The conversion's arithmetic, the offsets' range measured on a real LeRobot dataset, and every policy
type trained on relative chunks and acting with absolute targets that move with the hand."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from tests.helpers.policy import HEIGHT, IMAGE_KEY, POLICY_TYPES, WIDTH, random_batch, small_config

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.datasets import LeRobotDatasetMetadata
from lerobot.policies.factory import get_policy_class

from mosaic_policy.common.hand_relative import HandRelativeTargets, dataset_offset_stats


def converter(offset_low=-0.2, offset_high=0.2) -> HandRelativeTargets:
    """State normalised with mean 0.5 / std 2, actions with min -1 / max 3, offsets over [low, high] (no margin)."""
    relative = HandRelativeTargets()
    relative.state_mean.fill_(0.5)
    relative.state_std.fill_(2.0)
    relative.action_min.fill_(-1.0)
    relative.action_max.fill_(3.0)
    relative.offset_min.fill_(offset_low)
    relative.offset_max.fill_(offset_high)
    return relative


def test_offsets_of_known_targets_and_the_way_back():
    relative = converter()
    state = torch.tensor([[0.25, 0.0, -0.25, 9.0]])  # normalised: hand at (1.0, 0.5, 0.0); the 4th dim is ignored
    # absolute targets (1.1, 0.5, -0.2) and (0.9, 0.7, 0.0) normalised by min -1 / max 3: (a + 1) / 2 - 1
    targets = torch.tensor([[[1.1, 0.5, -0.2, 0.3], [0.9, 0.7, 0.0, -0.7]]])
    normalised = (targets[..., :3] + 1.0) / 2.0 - 1.0
    chunk = torch.cat([normalised, targets[..., 3:]], dim=-1)
    offsets = relative.to_relative(chunk, state)
    # offsets (0.1, 0, -0.2) and (-0.1, 0.2, 0) over [-0.2, 0.2]: offset / 0.2
    expected = torch.tensor([[[0.5, 0.0, -1.0, 0.3], [-0.5, 1.0, 0.0, -0.7]]])
    torch.testing.assert_close(offsets, expected)
    torch.testing.assert_close(relative.to_absolute(offsets, state), chunk)
    far = chunk.clone()
    far[..., 0] = 1.0  # 2 m from the hand: outside the offsets' range, clamped to its edge
    assert relative.to_relative(far, state)[..., 0].eq(1.0).all()


def test_every_frame_of_a_training_window_is_relative_to_its_own_hand():
    relative = converter(-5.0, 5.0)  # wide enough for every random target: nothing clamped
    chunks = torch.rand(2, 3, 4, 7) * 2 - 1  # (B, T, chunk, A)
    state = torch.randn(2, 3, 10) * 0.05
    offsets = relative.to_relative(chunks, state)
    for t in range(3):
        torch.testing.assert_close(offsets[:, t], relative.to_relative(chunks[:, t], state[:, t]))
    torch.testing.assert_close(relative.to_absolute(offsets, state), chunks, atol=1e-6, rtol=0)


def test_the_offsets_range_covers_every_chunk_of_the_dataset(door_datasets):
    agent_root, _ = door_datasets
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    stats = dataset_offset_stats(agent_root, meta.features, chunk=3)
    import pandas as pd

    frames = pd.concat(pd.read_parquet(path) for path in sorted((agent_root / "data").glob("*/*.parquet")))
    offsets = []
    for _, episode in frames.groupby("episode_index"):
        actions, states = np.stack(episode["action"]), np.stack(episode["observation.state"])
        for start in range(len(episode) - 2):
            offsets.append(actions[start : start + 3, :3] - states[start, :3])
    offsets = np.concatenate(offsets)
    np.testing.assert_allclose(stats["min"][:3], offsets.min(0), atol=1e-6)
    np.testing.assert_allclose(stats["max"][:3], offsets.max(0), atol=1e-6)
    only_first = dataset_offset_stats(agent_root, meta.features, chunk=3, episodes=[0])
    assert (only_first["max"][:3] <= stats["max"][:3] + 1e-6).all()


@pytest.mark.parametrize("policy_type", POLICY_TYPES)
def test_each_policy_fits_the_offsets_to_its_dataset_and_its_targets_move_with_the_hand(
    policy_type, door_datasets, tmp_path
):
    agent_root, demo_root = door_datasets
    meta = LeRobotDatasetMetadata("mosaic/door_panda", root=agent_root)
    config = small_config(
        policy_type=policy_type, hand_relative_targets=True, demo_repo_id="mosaic/door_sawyer", demo_root=str(demo_root)
    )
    torch.manual_seed(0)
    policy = get_policy_class(policy_type)(config, dataset_meta=meta)
    offsets = dataset_offset_stats(agent_root, meta.features, config.action_chunk)
    span = offsets["max"][:3] - offsets["min"][:3]
    np.testing.assert_allclose(policy.hand_relative.offset_max.numpy(), offsets["max"][:3] + 0.05 * span, rtol=1e-5)
    np.testing.assert_allclose(policy.hand_relative.state_std.numpy(), meta.stats["observation.state"]["std"][:3])

    loss, _ = policy.train().forward(random_batch(config, batch_size=2))
    loss.backward()
    assert torch.isfinite(loss)

    policy.save_pretrained(tmp_path / "saved")
    loaded = get_policy_class(policy_type).from_pretrained(tmp_path / "saved").eval()  # no dataset: from the checkpoint
    torch.testing.assert_close(loaded.hand_relative.offset_min, policy.hand_relative.offset_min)

    image, demo = torch.rand(1, 3, HEIGHT, WIDTH), torch.rand(4, 3, HEIGHT, WIDTH)
    state = torch.randn(1, 10)
    moved = state.clone()
    moved[0, :3] += 0.5  # normalised: the hand 0.5 standard deviations further along x, y and z
    targets = []
    for hand in (state, moved):
        loaded.reset()
        loaded.set_demo(demo)
        targets.append(loaded.predict_action_chunk({IMAGE_KEY: image, "observation.state": hand}))
    relative = loaded.hand_relative
    shift_m = 0.5 * (relative.state_std + 1e-8)
    expected = 2.0 * shift_m / (relative.action_max - relative.action_min)  # the same move in normalised targets
    torch.testing.assert_close(targets[1][..., :3] - targets[0][..., :3], expected.expand(1, config.action_chunk, 3))
    torch.testing.assert_close(targets[1][..., 3:], targets[0][..., 3:])  # rotation and gripper stay absolute


def test_without_a_state_feature_or_its_hand_position_it_is_a_one_line_error():
    config = small_config(hand_relative_targets=True)
    config.input_features = {k: v for k, v in config.input_features.items() if k != "observation.state"}
    with pytest.raises(ValueError, match="hand_relative_targets=false"):
        get_policy_class("mosaic")(config)

    other_layout = SimpleNamespace(features={"observation.state": {"names": ["joint_0", "joint_1", "joint_2"]}})
    with pytest.raises(ValueError, match="start with the hand's x, y, z"):
        get_policy_class("mosaic")(small_config(hand_relative_targets=True), dataset_meta=other_layout)

    config = small_config(hand_relative_targets=True)
    config.input_features["observation.state"] = PolicyFeature(type=FeatureType.STATE, shape=(10,))
    policy = get_policy_class("mosaic")(config).eval()
    policy.set_demo(torch.rand(4, 3, HEIGHT, WIDTH))
    with pytest.raises(ValueError, match="give it observation.state"):
        policy.select_action({IMAGE_KEY: torch.rand(1, 3, HEIGHT, WIDTH)})
    batch = random_batch(config, batch_size=2)
    del batch["observation.state"]
    with pytest.raises(ValueError, match="observation.state .the hand position. in every training batch"):
        policy.train().forward(batch)
