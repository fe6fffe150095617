"""The shared building blocks, each alone: trunk, discretised logistic, attention, contrastive module."""

import math

import pytest
import torch
from tests.helpers.policy import random_batch, small_config

from mosaic_policy.common.attention import NonLocalAttentionLayer, NonLocalAttentionStack, spatio_temporal_encoding
from mosaic_policy.mosaic.contrastive import (
    TemporalContrastiveModule,
    ema_momentum,
    positive_indices,
)
from mosaic_policy.common.discretized_logistic import DiscretizedLogisticMixture
from mosaic_policy.common.conv_trunk import ConvTrunk
from mosaic_policy.common.keypoints import SpatialSoftArgmax
from mosaic_policy.common.resnet_trunk import ResNetTrunk
from mosaic_policy.common.trunks import make_trunk
from mosaic_policy.common.weight_average import ema_update, frozen_copy
from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy


def test_trunk_gives_256x7x12_features_at_100x180():
    trunk = ResNetTrunk().eval()
    with torch.no_grad():
        features = trunk(torch.rand(1, 3, 100, 180))
    assert features.shape == (1, 256, 7, 12)
    assert features.dtype == torch.float32


@pytest.mark.parametrize("height, width", [(32, 56), (48, 88), (100, 180), (33, 57)])
def test_conv_trunk_gives_the_resnet_trunks_feature_shape(height, width):
    """`vision_backbone="conv"` changes nothing downstream: same channels, same h x w for any image size."""
    resnet, conv = ResNetTrunk().eval(), ConvTrunk().eval()
    with torch.no_grad():
        expected = resnet(torch.rand(2, 3, height, width)).shape
        features = conv(torch.rand(2, 3, height, width))
    assert features.shape == expected
    assert conv.feature_shape(height, width) == resnet.feature_shape(height, width) == tuple(expected[1:])
    assert conv.out_channels == resnet.out_channels == expected[1]
    assert sum(p.numel() for p in conv.parameters()) < sum(p.numel() for p in resnet.parameters()) / 5


@pytest.mark.parametrize(
    "backbone, keypoints, trunk_class", [("resnet18", 0, ResNetTrunk), ("conv", 0, ConvTrunk), ("conv", 16, ConvTrunk)]
)
def test_every_backbone_builds_through_make_trunk_and_its_fused_copy_matches_the_eval_trunk(backbone, keypoints, trunk_class):
    torch.manual_seed(0)
    trunk = make_trunk(small_config(vision_backbone=backbone, conv_keypoints=keypoints))
    assert type(trunk) is trunk_class
    trunk.train()
    with torch.no_grad():
        for _ in range(3):  # BatchNorm running statistics away from their initial 0 / 1
            trunk(torch.rand(4, 3, 32, 56) * 0.5 + 0.3)
    trunk.eval()
    fused = trunk.fused_for_inference()
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fused.modules())
    assert not any(p.requires_grad for p in fused.parameters())
    images = torch.rand(3, 3, 32, 56)
    with torch.no_grad():
        torch.testing.assert_close(fused(images), trunk(images), atol=1e-4, rtol=1e-4)


def test_spatial_soft_argmax_finds_where_a_map_peaks_between_grid_points():
    """A map that fires at one location gives that location's coordinates; two equal peaks give their midpoint,
    finer than the grid."""
    soft_argmax = SpatialSoftArgmax(channels=1, n_keypoints=1)
    torch.nn.init.ones_(soft_argmax.conv.weight)
    features = torch.full((2, 1, 3, 5), -1e4)
    features[0, 0, 0, 0] = 0.0  # top left
    features[1, 0, 2, 3] = features[1, 0, 2, 4] = 0.0  # bottom row, between the last two columns
    torch.testing.assert_close(soft_argmax(features), torch.tensor([[-1.0, -1.0], [0.75, 1.0]]))


def test_conv_trunk_keypoints_fill_the_last_channels_with_the_third_layers_soft_argmax():
    """`conv_keypoints=K`: the same feature shape; the last 2K channels are the keypoints of the H/8 x W/8 map,
    the same at every location, in [-1, 1]."""
    torch.manual_seed(0)
    trunk = ConvTrunk(256, keypoints=16).eval()
    images = torch.rand(2, 3, 48, 88)
    with torch.no_grad():
        features = trunk(images)
        finer = trunk.layers[:9]((images - 0.5) / 0.25)
        expected = trunk.keypoints(finer)
    assert features.shape == (2, 256, 3, 6) and finer.shape[2:] == (6, 11)
    points = features[:, -32:]
    assert torch.equal(points, points[:, :, :1, :1].expand_as(points))
    torch.testing.assert_close(points[:, :, 0, 0], expected)
    assert points.abs().max() <= 1
    assert trunk.layers[-3].out_channels == 256 - 32


# -- discretised logistic ----------------------------------------------------------------------------------


def _sigmoid(x):
    return 1.0 / (1.0 + math.exp(-x))


def _direct_bin_probability(x, weights, means, scales, num_bins, low=-1.0, high=1.0):
    """P(bin of x) of a logistic mixture, written out from the definition with floats."""
    width = (high - low) / (num_bins - 1)
    k = round((x - low) / width)
    centre = low + k * width
    total = 0.0
    for w, mu, s in zip(weights, means, scales, strict=True):
        upper = 1.0 if k == num_bins - 1 else _sigmoid((centre + width / 2 - mu) / s)
        lower = 0.0 if k == 0 else _sigmoid((centre - width / 2 - mu) / s)
        total += w * (upper - lower)
    return total


def test_discretized_logistic_nll_matches_direct_computation():
    logits = [0.3, -1.0, 0.7]
    weights = [math.exp(v) / sum(math.exp(u) for u in logits) for u in logits for v in [u]]
    means = [-0.5, 0.1, 0.8]
    log_scales = [-2.0, -3.0, -1.5]
    scales = [math.exp(v) for v in log_scales]
    xs = [-1.0, -0.999, -0.52, 0.0, 0.1, 0.13, 0.79, 1.0, 0.4]
    dist = DiscretizedLogisticMixture(
        torch.tensor(logits, dtype=torch.float64).expand(len(xs), 3),
        torch.tensor(means, dtype=torch.float64).expand(len(xs), 3),
        torch.tensor(log_scales, dtype=torch.float64).expand(len(xs), 3),
        num_bins=256,
    )
    got = dist.log_prob(torch.tensor(xs, dtype=torch.float64))
    expected = torch.tensor([math.log(_direct_bin_probability(x, weights, means, scales, 256)) for x in xs], dtype=torch.float64)
    torch.testing.assert_close(got, expected, rtol=1e-6, atol=1e-8)


def test_discretized_logistic_bins_sum_to_one_and_samples_follow_the_mixture():
    num_bins = 16
    params = dict(
        logit_probs=torch.tensor([[0.0, 1.0]]),
        means=torch.tensor([[-0.6, 0.4]]),
        log_scales=torch.tensor([[-1.5, -2.0]]),
    )
    dist = DiscretizedLogisticMixture(**params, num_bins=num_bins)
    centres = torch.linspace(-1, 1, num_bins)
    probs = torch.stack([dist.log_prob(c.view(1)).exp() for c in centres]).squeeze(-1)
    assert probs.sum().item() == pytest.approx(1.0, abs=1e-5)

    n = 40_000
    many = DiscretizedLogisticMixture(*(v.expand(n, 2) for v in params.values()), num_bins=num_bins)
    samples = many.sample(torch.Generator().manual_seed(0))
    bins = torch.round((samples + 1) / (2 / (num_bins - 1))).long()
    empirical = torch.bincount(bins, minlength=num_bins).float() / n
    assert (empirical - probs).abs().sum().item() < 0.03  # total variation (x2) within sampling noise
    assert torch.allclose(samples, many.snap(samples))  # samples are bin centres


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_discretized_logistic_edge_bins_absorb_both_tails_in_float32(dtype):
    """256 bins, a component far past either edge: the edge bin holds (almost) all of its mass.

    Gripper labels and every per-dimension min/max sit exactly on +-1 after MIN_MAX normalisation.
    """
    num_bins = 256
    centres = torch.linspace(-1, 1, num_bins, dtype=dtype)
    for mean, edge in ((-1.5, -1.0), (1.5, 1.0)):
        dist = DiscretizedLogisticMixture(
            torch.zeros(num_bins, 1, dtype=dtype),
            torch.full((num_bins, 1), mean, dtype=dtype),
            torch.full((num_bins, 1), math.log(0.018), dtype=dtype),
            num_bins=num_bins,
        )
        log_probs = dist.log_prob(centres)
        assert log_probs.exp().sum().item() == pytest.approx(1.0, abs=1e-4)
        edge_log_prob = dist.log_prob(torch.tensor([edge], dtype=dtype).expand(num_bins))[0].item()
        assert edge_log_prob == pytest.approx(0.0, abs=1e-4)
    # a mixture inside the range sums to one in float32 too
    dist = DiscretizedLogisticMixture(
        torch.tensor([[0.0, 1.0]], dtype=dtype).expand(num_bins, 2),
        torch.tensor([[-0.97, 0.99]], dtype=dtype).expand(num_bins, 2),
        torch.tensor([[-4.0, -3.0]], dtype=dtype).expand(num_bins, 2),
        num_bins=num_bins,
    )
    assert dist.log_prob(centres).exp().sum().item() == pytest.approx(1.0, abs=1e-4)


# -- attention ---------------------------------------------------------------------------------------------


def _stack(pattern="mosaic"):
    torch.manual_seed(0)
    return NonLocalAttentionStack(channels=24, n_layers=2, n_heads=3, temperature=16.0, dropout=0.0, pattern=pattern).eval()


def test_observation_frames_are_independent_of_how_many_are_given():
    """7 training frames or 1 inference frame: the same output per frame (same encodings, no cross-frame attention)."""
    stack = _stack()
    demo = torch.randn(2, 24, 4, 3, 5) + spatio_temporal_encoding(24, [0, 1, 2, 3], 3, 5)
    obs = torch.randn(2, 24, 7, 3, 5) + spatio_temporal_encoding(24, [4], 3, 5)
    with torch.no_grad():
        _, all_frames, _ = stack(demo, obs)
        _, cache = stack.encode_demo(demo)
        for t in (0, 3, 6):
            one, _ = stack.attend_obs(obs[:, :, t : t + 1], cache)
            torch.testing.assert_close(one[:, :, 0], all_frames[:, :, t], rtol=1e-5, atol=1e-5)


def test_attention_weights_cover_own_and_demo_tokens():
    stack = _stack()
    demo, obs = torch.randn(1, 24, 4, 3, 5), torch.randn(1, 24, 2, 3, 5)
    with torch.no_grad():
        _, cache = stack.encode_demo(demo)
        _, weights = stack.attend_obs(obs, cache, return_weights=True)
    assert len(weights) == 2
    assert weights[0].shape == (1, 3, 2, 15, 15 + 4 * 15)  # (B, heads, T, queries, own + demo tokens)
    torch.testing.assert_close(weights[0].sum(-1), torch.ones(1, 3, 2, 15))


def test_demo_stream_is_updated_by_every_layer():
    stack = _stack()
    demo = torch.randn(1, 24, 4, 3, 5)
    with torch.no_grad():
        out, cache = stack.encode_demo(demo)
    assert not torch.allclose(out, demo)
    assert not torch.allclose(cache[0][0], cache[1][0])  # layer 2's keys come from layer 1's demo output


def test_full_pattern_runs():
    demo_out, obs_out, _ = _stack("full")(torch.randn(1, 24, 4, 3, 5), torch.randn(1, 24, 3, 3, 5))
    assert demo_out.shape == (1, 24, 4, 3, 5) and obs_out.shape == (1, 24, 3, 3, 5)


def _reference_forward_obs(layer, obs, demo_k, demo_v):
    """forward_obs without the fused kernel, written out with the layer's Conv3d modules (the reference the fused
    path must match): frame t's queries against [its own h*w keys, all demo keys] (the demo keys repeated per
    frame), one softmax."""
    b, c, t, h, w = obs.shape
    n_h, hw = layer.n_heads, h * w

    def heads(y):  # (B, C, T, h, w) -> (B, heads, T, hw, C/heads)
        return y.movedim(1, -1).reshape(b, t, hw, n_h, c // n_h).permute(0, 3, 1, 2, 4)

    def channel_last_norm(norm, y):
        return norm(y.movedim(1, -1)).movedim(-1, 1)

    q, k, v = heads(layer.query(obs)), heads(layer.key(obs)), heads(layer.value(obs))
    keys = torch.cat([k, demo_k.unsqueeze(2).expand(-1, -1, t, -1, -1)], dim=3)
    values = torch.cat([v, demo_v.unsqueeze(2).expand(-1, -1, t, -1, -1)], dim=3)
    weights = torch.softmax(q @ keys.transpose(-1, -2) / layer.temperature, dim=-1)  # (B, heads, T, hw, hw + D*hw)
    attended = (weights @ values).permute(0, 1, 4, 2, 3).reshape(b, c, t, h, w)  # heads-major channels
    x = channel_last_norm(layer.norm_attention, obs + layer.out(attended))
    return channel_last_norm(layer.norm_ffn, x + layer.ffn(x)), weights


def _grads(outputs, inputs):
    """Gradients of a fixed random weighting of the outputs (a plain sum would be flat through the LayerNorm)."""
    g = torch.Generator().manual_seed(1)
    loss = sum((o * torch.randn(o.shape, generator=g)).sum() for o in outputs)
    return torch.autograd.grad(loss, inputs)


@pytest.mark.parametrize("n_frames", [7, 1])
def test_fused_observation_attention_matches_the_explicit_computation(n_frames):
    """forward_obs without weights (one fused attention call) gives the explicit computation's output and
    gradients, for the inputs, the cached demo keys/values (so the demo stream) and every parameter."""
    torch.manual_seed(0)
    layer = NonLocalAttentionLayer(channels=24, n_heads=3, temperature=16.0, dropout=0.0).eval()
    demo = torch.randn(2, 24, 4, 3, 5, requires_grad=True)
    obs = torch.randn(2, 24, n_frames, 3, 5, requires_grad=True)
    inputs = (obs, demo, *layer.parameters())

    def run(forward_obs):
        demo_k, demo_v = layer.demo_keys_values(demo)  # the cache's layout, a view of channel-last tokens
        out, weights = forward_obs(obs, demo_k, demo_v)
        return out, weights, _grads([out], inputs)

    reference, reference_weights, reference_grads = run(lambda *a: _reference_forward_obs(layer, *a))
    fused, no_weights, fused_grads = run(lambda *a: layer.forward_obs(*a, return_weights=False))
    explicit, weights, explicit_grads = run(lambda *a: layer.forward_obs(*a, return_weights=True))
    assert no_weights is None
    torch.testing.assert_close(fused, reference, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(explicit, reference, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(weights, reference_weights, rtol=1e-5, atol=1e-5)
    # obs, demo and 16 parameter tensors; all but the key bias (it shifts every score of a query alike, which the
    # softmax ignores) have a gradient clearly above the tolerance, so the comparison is not of zeros
    assert len(fused_grads) == len(reference_grads) == 2 + 16
    flat = [p is layer.key.bias for p in inputs]
    for fused_grad, explicit_grad, reference_grad, is_flat in zip(
        fused_grads, explicit_grads, reference_grads, flat, strict=True
    ):
        assert is_flat or reference_grad.abs().max() > 1e-2
        torch.testing.assert_close(fused_grad, reference_grad, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(explicit_grad, reference_grad, rtol=1e-5, atol=1e-5)


def test_the_batch_expanded_demo_cache_of_acting_gives_the_same_fused_output():
    """Acting sets the demo once and expands its cache over the environments (a stride-0 batch dimension)."""
    torch.manual_seed(0)
    layer = NonLocalAttentionLayer(channels=24, n_heads=3, temperature=16.0).eval()
    with torch.no_grad():
        demo_k, demo_v = layer.demo_keys_values(torch.randn(1, 24, 4, 3, 5))
        obs = torch.randn(3, 24, 1, 3, 5)
        fused, _ = layer.forward_obs(obs, demo_k.expand(3, -1, -1, -1), demo_v.expand(3, -1, -1, -1))
        reference, _ = _reference_forward_obs(layer, obs, demo_k.expand(3, -1, -1, -1), demo_v.expand(3, -1, -1, -1))
    torch.testing.assert_close(fused, reference, rtol=1e-5, atol=1e-5)


def test_mosaic_policy_loss_and_gradients_are_those_of_the_explicit_attention(monkeypatch):
    """The whole MosaicPolicy forward (eval mode: no dropout, no augmentation) with the fused observation attention
    equals the same forward with the explicit reference attention, loss and every parameter's gradient."""
    torch.manual_seed(0)
    policy = MosaicPolicy(small_config()).eval()
    batch = random_batch(policy.config)
    params = [p for p in policy.parameters() if p.requires_grad]

    def loss_and_grads():
        loss, _ = policy.forward(batch)
        return loss, torch.autograd.grad(loss, params, allow_unused=True)

    fused_loss, fused_grads = loss_and_grads()
    monkeypatch.setattr(
        NonLocalAttentionLayer,
        "forward_obs",
        lambda self, obs, demo_k, demo_v, return_weights=False: _reference_forward_obs(self, obs, demo_k, demo_v),
    )
    reference_loss, reference_grads = loss_and_grads()
    torch.testing.assert_close(fused_loss, reference_loss, rtol=1e-5, atol=1e-5)
    compared = 0
    for fused_grad, reference_grad in zip(fused_grads, reference_grads, strict=True):
        assert (fused_grad is None) == (reference_grad is None)
        if fused_grad is not None:
            torch.testing.assert_close(fused_grad, reference_grad, rtol=1e-5, atol=1e-5)
            compared += 1
    assert compared > len(params) // 2


# -- contrastive -------------------------------------------------------------------------------------------


def test_positive_indices_modes():
    valid = torch.ones(2, 5, dtype=torch.bool)
    same = positive_indices(2, 5, "same", 0, valid)
    assert same.tolist() == list(range(10))
    fixed = positive_indices(2, 5, "fixed", 2, valid).reshape(2, 5)
    assert fixed[0].tolist() == [2, 3, 4, 1, 2]
    window = positive_indices(2, 5, "window", 1, valid, torch.Generator().manual_seed(0)).reshape(2, 5)
    offsets = window - torch.arange(10).reshape(2, 5)
    assert offsets.abs().max() <= 1 and (window[1] >= 5).all()
    valid[0, 3:] = False
    window = positive_indices(2, 5, "window", 4, valid, torch.Generator().manual_seed(1)).reshape(2, 5)
    assert (window[0, :3] < 3).all()  # padded frames are never positives of real ones


@pytest.mark.parametrize("objective", ["infonce", "byol"])
def test_contrastive_loss_is_lower_for_true_positives(objective):
    """After a few steps on a fixed batch of two noisy views, true pairs score far better than shuffled ones."""
    torch.manual_seed(0)
    module = TemporalContrastiveModule(feature_dim=32, dim=16, hidden_dim=64, objective=objective, temperature=0.1)
    online = torch.randn(24, 32)
    target = online + 0.05 * torch.randn(24, 32)
    valid = torch.ones(24, dtype=torch.bool)
    positives, shuffled = torch.arange(24), torch.roll(torch.arange(24), 5)
    optimizer = torch.optim.Adam(module.trainable_parameters(), lr=1e-2)
    for _ in range(60):
        loss = module.loss(online, module.keys(target), positives, valid).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        module.update_target(0.99)
    module.eval()
    with torch.no_grad():
        keys = module.keys(target)
        true_loss = module.loss(online, keys, positives, valid).mean()
        shuffled_loss = module.loss(online, keys, shuffled, valid).mean()
    assert true_loss < 0.5 * shuffled_loss


def test_bilinear_similarity_is_a_full_matrix():
    module = TemporalContrastiveModule(8, 4, 16, "infonce", 0.1)
    module.train()
    loss = module.loss(torch.randn(6, 8), module.keys(torch.randn(6, 8)), torch.arange(6), torch.ones(6, dtype=torch.bool))
    loss.mean().backward()
    off_diagonal = module.bilinear.grad - torch.diag(torch.diag(module.bilinear.grad))
    assert off_diagonal.abs().sum() > 0


def test_ema_schedule_and_update():
    assert ema_momentum(0, 100, 0.996) == pytest.approx(0.996)
    assert ema_momentum(50, 100, 0.996) == pytest.approx(0.998)
    assert ema_momentum(100, 100, 0.996) == pytest.approx(1.0)
    online = torch.nn.Linear(3, 3)
    target = frozen_copy(online)
    with torch.no_grad():
        online.weight.add_(1.0)
    before = target.weight.clone()
    ema_update(target, online, 0.9)
    torch.testing.assert_close(target.weight, 0.9 * before + 0.1 * online.weight)
    assert not target.weight.requires_grad
