"""MOSAIC on tensors: its defaults and options, the attention streams, gradients and the EMA target, acting with
a cached demo (and its attention weights), the loss balancing, errors. What every type does (shapes, learning,
checkpoints, demo conditioning, acting as training computes, also with the full attention pattern) is tested
once for all in test_all_policies.py."""

import math

import pytest
import torch
from tests.helpers.policy import HEIGHT, IMAGE_KEY, WIDTH, random_batch, small_config

from mosaic_policy import MosaicConfig
from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy


@pytest.fixture(scope="module")
def policy():
    torch.manual_seed(0)
    return MosaicPolicy(small_config())


def test_paper_defaults():
    config = MosaicConfig()
    assert (config.n_demo_frames, config.train_obs_frames, config.eval_obs_frames) == (4, 7, 1)
    assert (config.n_attention_layers, config.attention_temperature, config.action_bins) == (2, 16.0, 256)
    assert config.contrastive == "both" and config.optimizer_lr == 5e-4
    assert config.bc_loss_weight == config.inverse_loss_weight == config.contrastive_loss_weight == 1.0
    # the paper's time scale at 20 Hz: 7 frames 0.25 s apart, one query per 5 control steps; images only
    assert config.observation_delta_indices == [0, 5, 10, 15, 20, 25, 30]
    assert config.action_delta_indices == list(range(35)) and config.action_chunk == 5
    assert config.use_state is False
    assert config.vision_backbone == "resnet18"


@pytest.mark.parametrize(
    "field, value",
    [
        ("contrastive", "sometimes"),
        ("contrastive_positive", "nearby"),
        ("n_demo_frames", 1),
        ("vision_backbone", "resnet50"),
        ("summary_dim", 0),
        ("variation_loss_weight", -1.0),
    ],
)
def test_config_rejects_bad_values_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        MosaicConfig(**{field: value})


def test_a_bad_vision_backbone_is_a_one_line_error_naming_the_choices():
    with pytest.raises(ValueError) as error:
        MosaicConfig(vision_backbone="resnet50")
    message = str(error.value)
    assert "\n" not in message and "'resnet50'" in message
    assert "resnet18" in message and "conv" in message and "--policy.vision_backbone=" in message


def test_the_attention_streams_keep_the_feature_maps(policy):
    batch = random_batch(policy.config)
    encoded = policy.model.encode(policy.model.trunk, policy.model.attention, batch["demo_frames"], batch[IMAGE_KEY])
    c, h, w = policy.model.feature_shape
    for stream, frames in (("demo", 4), ("obs", 3)):
        assert encoded[f"{stream}_pre"].shape == encoded[f"{stream}_post"].shape == (4, c, frames, h, w)


def test_gradients_reach_every_trainable_parameter_and_none_reach_the_target(policy):
    policy.train()
    policy.zero_grad(set_to_none=True)
    loss, _ = policy.forward(random_batch(policy.config, seed=1))
    loss.backward()
    trainable = {n for n, p in policy.named_parameters() if p.requires_grad}
    missing = [n for n, p in policy.named_parameters() if p.requires_grad and (p.grad is None or not p.grad.abs().sum() > 0)]
    assert not missing
    frozen = [n for n, p in policy.named_parameters() if not p.requires_grad]
    assert frozen and all(n.startswith(("target_", "model.contrastive_before.target_projector", "model.contrastive_after.target_projector")) for n in frozen)
    assert all(p.grad is None for n, p in policy.named_parameters() if n in frozen)
    assert {id(p) for p in policy.get_optim_params()} == {id(p) for n, p in policy.named_parameters() if n in trainable}


def test_ema_target_moves_after_update(policy):
    policy.train()
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=1e-3)
    target_before = {n: p.clone() for n, p in policy.named_parameters() if not p.requires_grad}
    loss, _ = policy.forward(random_batch(policy.config, seed=2))
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    assert all(torch.equal(target_before[n], p) for n, p in policy.named_parameters() if n in target_before)
    step = int(policy.ema_step)
    policy.update()
    assert int(policy.ema_step) == step + 1
    moved = [n for n, p in policy.named_parameters() if n in target_before and not torch.equal(target_before[n], p)]
    assert any(n.startswith("target_trunk") for n in moved)
    assert any(n.startswith("target_attention") for n in moved)
    assert any("target_projector" in n for n in moved)  # the original code never updated it


def test_select_action_uses_the_cached_demo_and_matches_the_training_path(policy):
    policy.eval()
    policy.reset()
    with pytest.raises(RuntimeError, match="set_demo"):
        policy.select_action({IMAGE_KEY: torch.rand(1, 3, HEIGHT, WIDTH), "observation.state": torch.randn(1, 10)})
    video = (torch.rand(30, HEIGHT, WIDTH, 3) * 255).to(torch.uint8)  # a whole demo video, channels last
    policy.set_demo(video)
    assert policy.has_demo
    frames = torch.rand(2, 3, 3, HEIGHT, WIDTH)
    state = torch.randn(2, 3, 10)
    with torch.no_grad():
        from mosaic_policy.common.paired_sampling import demo_frame_indices

        demo_frames = (video[demo_frame_indices(30, 4)].permute(0, 3, 1, 2).float() / 255).expand(2, -1, -1, -1, -1)
        encoded = policy.model.encode(policy.model.trunk, policy.model.attention, demo_frames, frames)
        expected = policy.model.action_distribution(policy.model.frame_embeddings(encoded["obs_post"]), state).mode()
    chunk = policy.config.action_chunk
    assert chunk == 2
    expected = expected.reshape(2, 3, chunk, 7)
    # One query per chunk: frame 0's two targets, in order (frame 1 is not looked at), then frame 2's first.
    for t, (frame, target) in enumerate([(0, 0), (0, 1), (2, 0)]):
        action = policy.select_action({IMAGE_KEY: frames[:, t], "observation.state": state[:, t]})
        assert action.shape == (2, 7) and action.dtype == torch.float32
        torch.testing.assert_close(action, expected[:, frame, target], atol=2 / 255, rtol=0)
    policy.select_action({IMAGE_KEY: frames[:, 0], "observation.state": state[:, 0]})  # empties the queue
    action, weights = policy.predict_with_attention({IMAGE_KEY: frames[:, 1], "observation.state": state[:, 1]})
    torch.testing.assert_close(action, expected[:, 1, 0], atol=2 / 255, rtol=0)
    assert len(weights) == policy.config.n_attention_layers
    assert weights[0].shape == (2, policy.config.n_attention_heads, 1, 8, 8 + 4 * 8)
    chunk_out = policy.predict_action_chunk({IMAGE_KEY: frames[:, 0], "observation.state": state[:, 0]})
    assert chunk_out.shape == (2, chunk, 7)
    policy.reset()
    assert not policy.has_demo


def test_wrong_image_size_is_a_clear_error(policy):
    policy.train()
    batch = random_batch(policy.config, height=40, width=56)
    with pytest.raises(ValueError, match=r"built for \(3, 32, 56\)"):
        policy.forward(batch)
    policy.eval()
    with pytest.raises(ValueError, match="resize"):
        policy.set_demo(torch.rand(4, 3, 100, 180))


@pytest.mark.parametrize(
    "overrides",
    [
        {"contrastive": "off"},
        {"contrastive": "before", "contrastive_objective": "byol"},
        {"contrastive": "after", "contrastive_positive": "fixed", "positive_window": 1},
        {"contrastive_positive": "same", "n_attention_layers": 1, "n_demo_frames": 3},
        {"attention_pattern": "full", "use_state": False},
        {"demo_summary": True, "summary_hidden_dim": 32, "summary_dim": 16},
        {"variation_loss_weight": 5.0, "contrastive": "off"},
    ],
)
def test_ablations_train(overrides):
    policy = MosaicPolicy(small_config(**overrides)).train()
    batch = random_batch(policy.config, batch_size=2)
    loss, info = policy.forward(batch)
    loss.backward()
    policy.update()
    assert torch.isfinite(loss)
    assert ("contrastive_loss" in info) == (overrides.get("contrastive", "both") != "off")


def test_the_demo_summary_is_off_by_default_and_reads_the_demo_frames_in_order():
    """Off (the paper's model): no summary weights, so checkpoints and initialisation stay the paper's. On: a
    cached vector per demonstration that changes when the demo frames are reversed, and gradients reach it."""
    assert not any("summary" in name for name in MosaicPolicy(small_config()).state_dict())
    torch.manual_seed(0)
    policy = MosaicPolicy(small_config(demo_summary=True, summary_hidden_dim=32, summary_dim=16)).eval()
    demo = torch.rand(1, policy.config.n_demo_frames, 3, HEIGHT, WIDTH)
    with torch.no_grad():
        forward, backward = (policy.encode_demo(frames)["summary"] for frames in (demo, demo.flip(1)))
    assert forward.shape == (1, 16)
    assert (forward - backward).abs().max() > 1e-4
    policy.train()
    loss, _ = policy.forward(random_batch(policy.config, batch_size=2))
    loss.backward()
    summary_parameters = [(n, p) for n, p in policy.model.named_parameters() if n.startswith("summary")]
    assert summary_parameters
    for name, parameter in summary_parameters:
        assert parameter.grad is not None and parameter.grad.abs().sum() > 0, name


def test_the_variation_loss_is_off_by_default_and_trains_the_demonstration_stream():
    """Off (the paper's model): no projector weights, no logged figure. On: the loss is logged, it is 0 for a batch
    whose variations are all different (nothing to group), and its gradient reaches the trunk through the demo
    frames alone (the observation frames' and the other losses' are switched off)."""
    assert not any("variation" in name for name in MosaicPolicy(small_config()).state_dict())
    torch.manual_seed(0)
    config = small_config(variation_loss_weight=1.0, contrastive="off", bc_loss_weight=0.0, inverse_loss_weight=0.0)
    policy = MosaicPolicy(config).train()
    batch = random_batch(policy.config, batch_size=4)  # two variations, two samples each
    loss, info = policy.forward(batch)
    assert info["variation_loss"] > 0 and 0.0 <= info["variation_nearest"] <= 1.0
    loss.backward()
    trunk_gradient = sum(p.grad.abs().sum() for p in policy.model.trunk.parameters() if p.grad is not None)
    assert trunk_gradient > 0
    batch["task"] = ["a", "b", "c", "d"]
    _, info = policy.forward(batch)
    assert info["variation_loss"] == 0.0 and "variation_nearest" not in info
    assert "variation_loss" not in MosaicPolicy(small_config()).train().forward(random_batch(config))[1]


def test_the_variation_loss_of_known_projections():
    """Two variations, two samples each, the same variation's projections identical and the other's orthogonal:
    each sample's one positive has similarity 1 against two negatives at 0, so the loss is
    log(1 + 2 exp(-1 / t)); a variation with a single sample has no positive and a loss of 0. The logged share of
    samples whose nearest other projection shows their variation: 1 when grouped, 0 when swapped, none to tell
    when no two samples share a variation."""
    from mosaic_policy.mosaic.variation_contrastive import nearest_is_same_variation, variation_contrastive_loss

    x, y = torch.tensor([1.0, 0.0]), torch.tensor([0.0, 2.0])
    loss = variation_contrastive_loss(torch.stack([x, x, y, y]), ["push", "push", "pull", "pull"], 0.5)
    torch.testing.assert_close(loss, torch.full((4,), math.log(1 + 2 * math.exp(-2.0))))
    loss = variation_contrastive_loss(torch.stack([x, x, y]), ["push", "push", "pull"], 0.5)
    torch.testing.assert_close(loss[2], torch.tensor(0.0))
    torch.testing.assert_close(loss[0], torch.tensor(math.log(1 + math.exp(-2.0))))
    assert nearest_is_same_variation(torch.stack([x, x, y]), ["push", "push", "pull"]) == 1.0
    assert nearest_is_same_variation(torch.stack([x, y, x, y]), ["push", "push", "pull", "pull"]) == 0.0
    assert nearest_is_same_variation(torch.stack([x, y]), ["push", "pull"]) is None
    with pytest.raises(ValueError, match="3 projections but 2 variation labels"):
        variation_contrastive_loss(torch.stack([x, x, y]), ["push", "pull"], 0.5)


def test_loss_is_averaged_per_variation_then_per_task():
    from mosaic_data.tasks.spec import VARIATIONS

    door = [v.description for v in VARIATIONS["door"]]
    drawer = [v.description for v in VARIATIONS["drawer"]]
    policy = MosaicPolicy(small_config(contrastive="off", augment=False))
    batch = {"task": [door[0], door[0], door[1], drawer[0]]}
    weights = policy.conditioning.sample_weights(batch, 4, "cpu")
    # two tasks (1/2 each); door has two variations (1/4 each); door[0] has two samples (1/8 each)
    torch.testing.assert_close(weights, torch.tensor([1 / 8, 1 / 8, 1 / 4, 1 / 2]))


def test_loss_is_averaged_per_variation():
    policy = MosaicPolicy(small_config(contrastive="off", augment=False)).train()
    batch = random_batch(policy.config, batch_size=4)
    batch["task"] = ["a", "a", "a", "b"]
    per_sample, _ = policy.forward(batch, reduction="none")
    weights = policy.conditioning.sample_weights(batch, 4, "cpu")
    torch.testing.assert_close(weights, torch.tensor([1 / 6, 1 / 6, 1 / 6, 1 / 2]))
    loss, _ = policy.forward(batch)
    torch.testing.assert_close(loss, per_sample.mean(), rtol=1e-5, atol=1e-5)
