"""The T-OSIL policy on tensors: shapes, losses, causality, acting with a memory of past frames, save/load."""

import pytest
import torch
from conftest import HEIGHT, IMAGE_KEY, WIDTH, random_batch, small_config
from lerobot.configs import FeatureType, PolicyFeature

from mosaic_policy import TosilConfig
from mosaic_policy.tosil.modeling_tosil import SpatialSoftArgmax, TosilPolicy, point_targets


def tosil_config(**overrides) -> TosilConfig:
    return small_config(policy_type="tosil", **overrides)


@pytest.fixture(scope="module")
def policy() -> TosilPolicy:
    torch.manual_seed(0)
    return TosilPolicy(tosil_config())


def distribution_params(dist) -> torch.Tensor:
    """(..., chunk * A, n_mixtures, 3): everything that defines a discretised logistic mixture."""
    return torch.stack([dist.logit_probs, dist.means, dist.log_scales], dim=-1)


def test_paper_defaults_and_lerobot_finds_the_policy():
    from lerobot.policies.factory import get_policy_class

    config = TosilConfig()
    assert (config.n_attention_layers, config.n_attention_heads, config.attention_temperature) == (2, 4, 16.0)
    assert config.bc_loss_weight == config.inverse_loss_weight == config.point_loss_weight == 1.0
    assert config.point_horizon == config.train_obs_frames - 1
    assert get_policy_class("tosil") is TosilPolicy


def test_shapes_through_the_model(policy):
    policy.train()
    batch = random_batch(policy.config)
    c, h, w = policy.model.feature_shape
    assert (c, h, w) == (256, 2, 4)
    obs_out = policy.model.encode(policy.model.trunk, batch["demo_frames"], batch[IMAGE_KEY])
    assert obs_out.shape == (4, c, 3, h, w)
    embeddings = policy.model.frame_embeddings(obs_out)
    assert embeddings.shape == (4, 3, policy.config.embed_dim)
    dist = policy.model.action_distribution(embeddings, None)
    assert dist.means.shape == (4, 3, 7 * policy.config.action_chunk, policy.config.n_mixtures)
    assert policy.model.point_head(obs_out).shape == (4, 3, 3)
    loss, info = policy.forward(batch)
    assert loss.dim() == 0 and torch.isfinite(loss)
    assert {"bc_loss", "inverse_loss", "point_loss", "loss"} <= set(info) and "contrastive_loss" not in info
    per_sample, _ = policy.forward(batch, reduction="none")
    assert per_sample.shape == (4,)

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
def test_a_frame_never_sees_later_observation_frames(policy, t):
    policy.eval()
    batch = random_batch(policy.config, batch_size=2, seed=4)
    obs = batch[IMAGE_KEY]
    perturbed = obs.clone()
    perturbed[:, t + 1] = torch.rand_like(perturbed[:, t + 1])

    def outputs(frames):
        with torch.no_grad():
            obs_out = policy.model.encode(policy.model.trunk, batch["demo_frames"], frames)
            embeddings = policy.model.frame_embeddings(obs_out)
            params = distribution_params(policy.model.action_distribution(embeddings, None))
            return embeddings, params, policy.model.point_head(obs_out)

    for before, after in zip(outputs(obs), outputs(perturbed), strict=True):
        torch.testing.assert_close(after[:, : t + 1], before[:, : t + 1], atol=1e-6, rtol=0)
        assert not torch.allclose(after[:, t + 1], before[:, t + 1], atol=1e-4)


def test_acting_with_a_memory_equals_the_causal_training_computation(policy):
    """Frame k acted on after frames 0..k-1 gets the distribution the training forward gives the last frame of
    a sample of its last train_obs_frames frames (one demo set for a batch of 2 environments)."""
    policy.eval()
    g = torch.Generator().manual_seed(5)
    demo = torch.rand(policy.config.n_demo_frames, 3, HEIGHT, WIDTH, generator=g)
    frames = torch.rand(2, 5, 3, HEIGHT, WIDTH, generator=g)  # more frames than the memory holds (3)
    policy.reset()
    policy.set_demo(demo)
    t_max = policy.config.train_obs_frames
    # The acting trunk is the BatchNorm-folded copy (equal to float rounding); the same one on both sides here.
    trunk = policy.trunk_for_inference()
    expected = []
    with torch.no_grad():
        for k in range(frames.shape[1]):
            window = frames[:, max(0, k - t_max + 1) : k + 1]
            obs_out = policy.model.encode(trunk, demo.expand(2, -1, -1, -1, -1), window)
            dist = policy.model.action_distribution(policy.model.frame_embeddings(obs_out)[:, -1], None)
            expected.append(dist)
    with torch.no_grad():
        for k in range(frames.shape[1]):
            acted = policy.chunk_distribution(frames[:, k], None, policy._context)
            torch.testing.assert_close(distribution_params(acted), distribution_params(expected[k]), atol=1e-5, rtol=0)

    policy.set_demo(demo)  # a new episode forgets the frames; select_action queries once per chunk
    chunk = policy.config.action_chunk
    for k in range(frames.shape[1]):
        for j in range(chunk):
            action = policy.select_action({IMAGE_KEY: frames[:, k]})
            assert action.shape == (2, 7)
            mode = expected[k].mode().reshape(2, chunk, 7)
            torch.testing.assert_close(action, mode[:, j], atol=2 / 255, rtol=0)
    assert policy.predict_action_chunk({IMAGE_KEY: frames[:, 0]}).shape == (2, chunk, 7)
    policy.reset()
    assert not policy.has_demo


def test_a_demo_for_some_environments_does_not_fit_another_batch(policy):
    policy.eval()
    policy.reset()
    policy.set_demo(torch.rand(2, 4, 3, HEIGHT, WIDTH))
    with pytest.raises(ValueError, match="set_demo"):
        policy.select_action({IMAGE_KEY: torch.rand(3, 3, HEIGHT, WIDTH)})
    policy.reset()

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
