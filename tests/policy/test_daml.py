"""DAML's own parts on tensors: the inner step, the meta-gradient, acting with the adapted weights, its variants.
What every type does (shapes, learning, checkpoints, demo conditioning) is tested once for all in
test_all_policies.py."""

import pytest
import torch
from tests.helpers.policy import HEIGHT, IMAGE_KEY, WIDTH, random_batch, small_config

from mosaic_policy import DamlConfig
from mosaic_policy.common.demo_conditioned_policy import expand_to_batch
from mosaic_policy.common.paired_sampling import demo_frame_indices
from mosaic_policy.daml.modeling_daml import DamlPolicy


def _policy(**overrides) -> DamlPolicy:
    torch.manual_seed(0)
    return DamlPolicy(small_config(policy_type="daml", **overrides))


@pytest.fixture(scope="module")
def policy() -> DamlPolicy:
    return _policy()


def _frame(n: int = 2, seed: int = 5) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {IMAGE_KEY: torch.rand(n, 3, HEIGHT, WIDTH, generator=g), "observation.state": torch.randn(n, 10, generator=g)}


def _video(seed: int) -> torch.Tensor:
    """A whole demo video, channels last, uint8."""
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (20, HEIGHT, WIDTH, 3), generator=g, dtype=torch.uint8)


def _snapshot(policy: DamlPolicy) -> dict[str, torch.Tensor]:
    return {name: p.detach().clone() for name, p in policy.named_parameters()}


def _nonzero(grad: torch.Tensor | None) -> bool:
    return grad is not None and bool(grad.abs().sum() > 0)


@pytest.mark.parametrize("field, value", [("inner_steps", 0), ("n_policy_layers", 0), ("inner_lr", 0.0)])
def test_config_rejects_bad_values_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        DamlConfig(**{field: value})


def test_parameter_count_is_comparable_to_mosaics():
    """At the default sizes (100x180 images) the table's rows compare policies of similar capacity."""
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    shared = dict(height=100, width=180, embed_dim=256, head_hidden_dim=256)
    mosaic = MosaicPolicy(
        small_config(policy_type="mosaic", n_attention_heads=4, contrastive_dim=128, contrastive_hidden_dim=512, **shared)
    )
    own = DamlConfig()
    daml = DamlPolicy(
        small_config(
            policy_type="daml",
            policy_hidden_dim=own.policy_hidden_dim,
            adapt_loss_channels=own.adapt_loss_channels,
            **shared,
        )
    )

    def count(p):
        return sum(q.numel() for q in p.get_optim_params())

    assert 0.7 < count(daml) / count(mosaic) < 1.1, (count(daml), count(mosaic))


def test_acting_matches_the_training_path(policy):
    """set_demo adapts under no_grad (torch.func takes the inner gradient anyway) to the weights training uses."""
    policy.eval()
    policy.reset()
    video = _video(1)
    policy.set_demo(video)
    frame = _frame(2)
    demo = (video[demo_frame_indices(20, 4)].permute(0, 3, 1, 2).float() / 255).unsqueeze(0)
    with torch.enable_grad():
        keypoints = policy.model.frame_keypoints(policy.model.trunk, demo)
        adapted, _ = policy.adapt(keypoints)
    for name, tensor in adapted.items():
        torch.testing.assert_close(policy._context[name], tensor.detach(), atol=1e-4, rtol=1e-4)
    with torch.no_grad():
        obs = policy.model.frame_keypoints(policy.model.trunk, frame[IMAGE_KEY].unsqueeze(1))
        embeddings = policy.adapted_embeddings(expand_to_batch(adapted, 2), obs)[:, 0]
        expected = policy.model.action_distribution(embeddings, None).mode().reshape(2, -1, 7)
    torch.testing.assert_close(policy.predict_action_chunk(frame), expected, atol=2 / 255, rtol=0)


def test_inner_step_adapts_copies_per_sample_and_leaves_the_parameters_alone(policy):
    policy.train()
    batch = random_batch(policy.config, seed=3)
    before = _snapshot(policy)
    keypoints = policy.model.frame_keypoints(policy.model.trunk, batch["demo_frames"])
    adapted, loss_before = policy.adapt(keypoints)
    assert loss_before.shape == (4,)
    for name, original in policy.model.policy.named_parameters():
        assert adapted[name].shape == (4, *original.shape)
        for b in range(4):
            assert not torch.equal(adapted[name][b], original)  # every tensor moved for every sample
        assert not torch.equal(adapted[name][0], adapted[name][1])  # each demo its own weights
    policy.forward(batch)
    assert all(torch.equal(before[name], p) for name, p in policy.named_parameters())


def test_more_inner_steps_move_further(policy):
    keypoints = policy.model.frame_keypoints(policy.model.trunk, random_batch(policy.config, seed=4)["demo_frames"])
    one, _ = policy.adapt(keypoints)
    policy.config.inner_steps = 3
    try:
        three, _ = policy.adapt(keypoints)
    finally:
        policy.config.inner_steps = 1
    original = dict(policy.model.policy.named_parameters())
    moved = {n: [(w[n] - original[n]).norm().item() for w in (one, three)] for n in original}
    assert all(far > near for near, far in moved.values()), moved


def test_meta_gradient_reaches_every_parameter_through_the_second_order_path():
    policy = _policy().train()
    loss, _ = policy.forward(random_batch(policy.config, seed=1))
    loss.backward()
    missing = [n for n, p in policy.named_parameters() if not _nonzero(p.grad)]
    assert not missing
    assert (policy.model.log_inner_lr.grad != 0).all()  # every adapted tensor's rate learns


def test_first_order_leaves_the_adaptation_loss_untrained():
    """Detaching the inner gradient cuts the adaptation loss's only path to the outer loss: it gets no gradient
    (it stays at its initialisation); the initial weights, the trunk and the inner rates still learn."""
    policy = _policy(first_order=True).train()
    loss, _ = policy.forward(random_batch(policy.config, seed=1))
    loss.backward()
    assert all(p.grad is None for p in policy.model.adapt_loss.parameters())
    assert (policy.model.log_inner_lr.grad != 0).all()
    for module in (policy.model.policy, policy.model.action_head, policy.model.trunk, policy.model.keypoints):
        assert all(_nonzero(p.grad) for p in module.parameters())


def test_second_order_terms_change_the_meta_gradient():
    grads = {}
    for first_order in (False, True):
        policy = _policy(first_order=first_order).train()
        loss, _ = policy.forward(random_batch(policy.config, seed=1))
        loss.backward()
        grads[first_order] = policy.model.policy[0].weight.grad
    assert not torch.allclose(grads[False], grads[True])


@pytest.mark.parametrize(
    "overrides", [{"inner_steps": 2}, {"first_order": True, "n_policy_layers": 3}, {"use_state": True, "n_demo_frames": 3}]
)
def test_variants_train(overrides):
    policy = _policy(**overrides).train()
    batch = random_batch(policy.config, batch_size=2)
    loss, _ = policy.forward(batch)
    loss.backward()
    assert torch.isfinite(loss)
    policy.eval()
    policy.set_demo(batch["demo_frames"])
    assert policy.select_action(_frame(2)).shape == (2, 7)
