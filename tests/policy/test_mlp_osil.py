"""The MLP baseline end to end on tensors: shapes, learning, checkpoints, demo conditioning, and acting computing
what training computes."""

import pytest
import torch
from conftest import HEIGHT, IMAGE_KEY, WIDTH, random_batch, small_config

from mosaic_policy import MlpOsilConfig
from mosaic_policy.mlp_osil.modeling_mlp_osil import MlpOsilPolicy


def make_policy(**overrides) -> MlpOsilPolicy:
    torch.manual_seed(0)
    return MlpOsilPolicy(small_config(policy_type="mlp_osil", **overrides))


@pytest.fixture(scope="module")
def policy():
    return make_policy()


def distribution_params(distribution) -> tuple[torch.Tensor, ...]:
    return distribution.logit_probs, distribution.means, distribution.log_scales

@pytest.mark.parametrize("field", ["n_context_layers", "context_hidden_dim", "context_dim"])
def test_config_rejects_bad_values_naming_the_field(field):
    with pytest.raises(ValueError, match=field):
        MlpOsilConfig(**{field: 0})


def test_shapes_through_the_model(policy):
    config = policy.config
    batch = random_batch(config)
    embeddings = policy.model.encode(policy.model.trunk, batch["demo_frames"], batch[IMAGE_KEY])
    assert embeddings.shape == (4, config.train_obs_frames, config.embed_dim)
    distribution = policy.model.action_distribution(embeddings, None)
    assert distribution.means.shape == (4, config.train_obs_frames, 7 * config.action_chunk, config.n_mixtures)
    policy.train()
    loss, info = policy.forward(batch)
    assert loss.dim() == 0 and torch.isfinite(loss)
    assert {"bc_loss", "inverse_loss"} <= set(info) and "contrastive_loss" not in info
    per_sample, _ = policy.forward(batch, reduction="none")
    assert per_sample.shape == (4,)

    policy.eval()
    policy.reset()
    policy.set_demo(torch.rand(config.n_demo_frames, 3, HEIGHT, WIDTH))  # one demo shared by 2 environments
    observation = {IMAGE_KEY: torch.rand(2, 3, HEIGHT, WIDTH), "observation.state": torch.randn(2, 10)}
    action = policy.select_action(observation)
    assert action.shape == (2, 7) and action.dtype == torch.float32
    assert policy.predict_action_chunk(observation).shape == (2, config.action_chunk, 7)
    policy.reset()


def test_use_state_feeds_the_robot_state_to_the_action_head():
    policy = make_policy(use_state=True)
    loss, _ = policy.train().forward(random_batch(policy.config, batch_size=2))
    assert torch.isfinite(loss)
    policy.eval().set_demo(torch.rand(policy.config.n_demo_frames, 3, HEIGHT, WIDTH))
    image = torch.rand(2, 3, HEIGHT, WIDTH)
    with pytest.raises(ValueError, match="observation.state"):
        policy.predict_action_chunk({IMAGE_KEY: image})
    assert policy.predict_action_chunk({IMAGE_KEY: image, "observation.state": torch.randn(2, 10)}).shape == (2, 2, 7)


def test_a_demo_for_other_environments_is_a_clear_error(policy):
    policy.eval().reset()
    policy.set_demo(torch.rand(3, policy.config.n_demo_frames, 3, HEIGHT, WIDTH))
    with pytest.raises(ValueError, match="one demonstration per environment"):
        policy.predict_action_chunk({IMAGE_KEY: torch.rand(2, 3, HEIGHT, WIDTH)})
    policy.reset()

def test_actions_depend_on_the_demonstration(policy):
    policy.eval()
    image = torch.rand(2, 3, HEIGHT, WIDTH)
    shape = (1, policy.config.n_demo_frames, 3, HEIGHT, WIDTH)
    demos = [torch.zeros(shape), torch.zeros(shape), torch.ones(shape)]  # a dark demo twice, then a bright one
    with torch.no_grad():
        means = [policy.chunk_distribution(image, None, policy.encode_demo(demo)).means for demo in demos]
    assert torch.equal(means[0], means[1])
    # at initialisation the demo's effect is small but far above float rounding (about 1e-7)
    assert (means[0] - means[2]).abs().max() > 1e-4
    policy.reset()


def test_acting_matches_training_for_every_frame(policy):
    """No memory: each frame's action distribution is the training one of that frame, whatever came before."""
    policy.eval()
    t = policy.config.train_obs_frames
    demo = torch.rand(2, policy.config.n_demo_frames, 3, HEIGHT, WIDTH)
    obs = torch.rand(2, t, 3, HEIGHT, WIDTH)
    policy.reset()
    policy.set_demo(demo)  # the fused inference trunk from here on
    context = policy.encode_demo(demo)
    with torch.no_grad():
        training = policy.model.action_distribution(policy.model.encode(policy.model.trunk, demo, obs), None)
        for k in range(t):
            acting = policy.chunk_distribution(obs[:, k], None, context)
            for a, e in zip(distribution_params(acting), distribution_params(training)):
                torch.testing.assert_close(a, e[:, k], atol=1e-5, rtol=0)
    policy.reset()
