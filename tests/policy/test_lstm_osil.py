"""The LSTM baseline end to end on tensors: shapes, learning, checkpoints, demo conditioning, and acting frame by
frame computing what training computes."""

import pytest
import torch
from conftest import HEIGHT, IMAGE_KEY, WIDTH, random_batch, small_config

from mosaic_policy import LstmOsilConfig
from mosaic_policy.common.discretized_logistic import DiscretizedLogisticMixture
from mosaic_policy.lstm_osil.modeling_lstm_osil import LstmOsilPolicy


def make_policy(**overrides) -> LstmOsilPolicy:
    torch.manual_seed(0)
    return LstmOsilPolicy(small_config(policy_type="lstm_osil", **overrides))


@pytest.fixture(scope="module")
def policy():
    return make_policy()


def distribution_params(distribution) -> tuple[torch.Tensor, ...]:
    return distribution.logit_probs, distribution.means, distribution.log_scales


def assert_same_distribution(actual, expected, atol: float = 1e-5) -> None:
    for a, e in zip(distribution_params(actual), distribution_params(expected)):
        torch.testing.assert_close(a, e, atol=atol, rtol=0)

@pytest.mark.parametrize("field", ["n_lstm_layers", "lstm_hidden_dim"])
def test_config_rejects_bad_values_naming_the_field(field):
    with pytest.raises(ValueError, match=field):
        LstmOsilConfig(**{field: 0})


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
    policy.set_demo(torch.rand(1, policy.config.n_demo_frames, 3, HEIGHT, WIDTH))
    policy.predict_action_chunk({IMAGE_KEY: torch.rand(2, 3, HEIGHT, WIDTH)})
    with pytest.raises(ValueError, match="mid-episode"):  # the memory holds frames of 2 environments
        policy.predict_action_chunk({IMAGE_KEY: torch.rand(3, 3, HEIGHT, WIDTH)})
    policy.reset()

def test_actions_depend_on_the_demonstration(policy):
    policy.eval()
    image = torch.rand(2, 3, HEIGHT, WIDTH)
    shape = (1, policy.config.n_demo_frames, 3, HEIGHT, WIDTH)
    demos = [torch.zeros(shape), torch.zeros(shape), torch.ones(shape)]  # a dark demo twice, then a bright one
    with torch.no_grad():
        means = []
        for demo in demos:
            policy.reset_memory()
            means.append(policy.chunk_distribution(image, None, policy.encode_demo(demo)).means)
    assert torch.equal(means[0], means[1])
    # at initialisation the demo's effect is small but far above float rounding (about 1e-7)
    assert (means[0] - means[2]).abs().max() > 1e-4
    policy.reset()


def training_distribution(policy: LstmOsilPolicy, demo: torch.Tensor, obs: torch.Tensor):
    """What training computes for every frame of a sample (eval mode: no dropout, BatchNorm statistics)."""
    with torch.no_grad():
        return policy.model.action_distribution(policy.model.encode(policy.model.trunk, demo, obs), None)


def last_frame(distribution, k: int = -1) -> DiscretizedLogisticMixture:
    """Frame k's distribution of a (B, T, ...) one (the last frame by default)."""
    return DiscretizedLogisticMixture(*(p[:, k] for p in distribution_params(distribution)))


def test_acting_frame_by_frame_matches_training_over_the_frames_so_far():
    policy = make_policy(lstm_dropout=0.5).eval()  # dropout must be off when acting
    t = policy.config.train_obs_frames
    demo = torch.rand(2, policy.config.n_demo_frames, 3, HEIGHT, WIDTH)
    obs = torch.rand(2, t + 2, 3, HEIGHT, WIDTH)
    policy.reset()
    policy.set_demo(demo)  # the fused inference trunk from here on
    context = policy.encode_demo(demo)
    whole_sample = training_distribution(policy, demo, obs[:, :t])
    with torch.no_grad():
        for k in range(t + 2):
            acting = policy.chunk_distribution(obs[:, k], None, context)
            if k < t:  # frames 0..k of a sample: the LSTM is causal, so the whole sample's frame k
                expected = last_frame(whole_sample, k)
            else:  # the memory keeps the last train_obs_frames query frames, the span of a sample
                expected = last_frame(training_distribution(policy, demo, obs[:, k - t + 1 : k + 1]))
            assert_same_distribution(acting, expected)


def test_reset_forgets_the_episodes_frames():
    policy = make_policy().eval()
    demo = torch.rand(1, policy.config.n_demo_frames, 3, HEIGHT, WIDTH)
    frames = torch.rand(3, 1, 3, HEIGHT, WIDTH)
    policy.set_demo(demo)
    for frame in frames:
        policy.predict_action_chunk({IMAGE_KEY: frame})
    policy.reset()
    assert not policy.has_demo
    policy.set_demo(demo)
    with torch.no_grad():
        acting = policy.chunk_distribution(frames[-1], None, policy.encode_demo(demo))
    # the last frame alone, as the first frame of a sample: nothing of the previous episode is left
    assert_same_distribution(acting, last_frame(training_distribution(policy, demo, frames[-1][:, None])))
