"""T-OSIL's own parts on tensors: the point head (its targets, loss, shapes and causality) and its defaults.
What every type does (shapes, learning, checkpoints, demo conditioning, causality, acting with a memory of past
frames as training computes) is tested once for all in test_all_policies.py."""

import pytest
import torch
from tests.helpers.policy import IMAGE_KEY, random_batch, small_config
from lerobot.configs import FeatureType, PolicyFeature

from mosaic_policy import TosilConfig
from mosaic_policy.tosil.modeling_tosil import SpatialSoftArgmax, TosilPolicy, point_targets


def tosil_config(**overrides) -> TosilConfig:
    return small_config(policy_type="tosil", **overrides)


@pytest.fixture(scope="module")
def policy() -> TosilPolicy:
    torch.manual_seed(0)
    return TosilPolicy(tosil_config())


def test_paper_defaults_and_lerobot_finds_the_policy():
    from lerobot.policies.factory import get_policy_class

    config = TosilConfig()
    assert (config.n_attention_layers, config.n_attention_heads, config.attention_temperature) == (2, 4, 16.0)
    assert config.bc_loss_weight == config.inverse_loss_weight == config.point_loss_weight == 1.0
    assert config.point_horizon == config.train_obs_frames - 1
    assert get_policy_class("tosil") is TosilPolicy


def test_the_attended_feature_maps_and_the_point_head_shapes(policy):
    batch = random_batch(policy.config)
    c, h, w = policy.model.feature_shape
    obs_out = policy.model.encode(policy.model.trunk, batch["demo_frames"], batch[IMAGE_KEY])
    assert obs_out.shape == (4, c, 3, h, w)
    assert policy.model.point_head(obs_out).shape == (4, 3, 3)

def test_spatial_soft_argmax_finds_the_peak():
    features = torch.full((1, 2, 5, 9), -50.0)
    features[0, 0, 0, 0] = 50.0  # top left
    features[0, 1, 2, 8] = 50.0  # middle row, right edge
    torch.testing.assert_close(SpatialSoftArgmax()(features), torch.tensor([[[-1.0, -1.0], [1.0, 0.0]]]))


def test_point_targets_look_ahead_and_stop_at_the_last_real_action():
    actions = torch.arange(12, dtype=torch.float32)[None, :, None].expand(2, 12, 7).clone()  # value = position
    is_pad = torch.zeros(2, 12, dtype=torch.bool)
    is_pad[1, 5:] = True  # the second sample's episode ends after position 4
    is_pad[1, 0] = False
    targets, exists = point_targets(actions, is_pad, n_frames=3, frame_stride=2, horizon=2)
    # frame t looks at position (t + 2) * 2 = 4, 6, 8, clamped to the last real position (11, then 4)
    assert targets.shape == (2, 3, 3)
    torch.testing.assert_close(targets[..., 0], torch.tensor([[4.0, 6.0, 8.0], [4.0, 4.0, 4.0]]))
    assert exists.all()
    _, exists = point_targets(actions, torch.ones(2, 12, dtype=torch.bool), 3, 2, 2)
    assert not exists.any()  # no real action, no target


def test_loss_decreases_on_a_fixed_batch():
    torch.manual_seed(0)
    policy = TosilPolicy(tosil_config(augment=False)).train()
    batch = random_batch(policy.config, batch_size=2, seed=3)
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=1e-3)
    losses, point_losses = [], []
    for _ in range(30):
        loss, info = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
        point_losses.append(info["point_loss"])
    assert losses[-1] < 0.9 * losses[0], losses
    assert point_losses[-1] < 0.5 * point_losses[0], point_losses


@pytest.mark.parametrize("t", [0, 1])
def test_the_point_head_never_sees_later_observation_frames(policy, t):
    policy.eval()
    batch = random_batch(policy.config, batch_size=2, seed=4)
    obs = batch[IMAGE_KEY]
    perturbed = obs.clone()
    perturbed[:, t + 1] = torch.rand_like(perturbed[:, t + 1])
    with torch.no_grad():
        before, after = (
            policy.model.point_head(policy.model.encode(policy.model.trunk, batch["demo_frames"], frames))
            for frames in (obs, perturbed)
        )
    torch.testing.assert_close(after[:, : t + 1], before[:, : t + 1], atol=1e-6, rtol=0)
    assert not torch.allclose(after[:, t + 1], before[:, t + 1], atol=1e-4)


def test_point_loss_weight_zero_removes_the_point_loss():
    torch.manual_seed(0)
    with_point = TosilPolicy(tosil_config(augment=False)).eval()
    torch.manual_seed(0)
    without = TosilPolicy(tosil_config(augment=False, point_loss_weight=0.0)).eval()
    assert without.model.point_head is None
    point_keys = {k for k in with_point.state_dict() if k.startswith("model.point_head.")}
    assert point_keys and with_point.state_dict().keys() - point_keys == without.state_dict().keys()
    batch = random_batch(with_point.config, batch_size=2, seed=7)
    with torch.no_grad():
        sample = with_point.training_sample(batch)
        full, info = with_point.compute_loss(sample)
        reduced, info_without = without.compute_loss(without.training_sample(batch))
        obs_out = with_point.model.encode(with_point.model.trunk, sample.demo, sample.obs)
        point = with_point.point_loss(obs_out, sample)
    assert "point_loss" in info and "point_loss" not in info_without
    torch.testing.assert_close(reduced, full - point, atol=1e-4, rtol=1e-5)


def test_point_prediction_needs_an_xyz_action():
    features = {"action": PolicyFeature(FeatureType.ACTION, (2,))}
    with pytest.raises(ValueError, match="point_loss_weight=0"):
        TosilPolicy(tosil_config(output_features=features))
    assert TosilPolicy(tosil_config(output_features=features, point_loss_weight=0.0)).action_dim == 2
