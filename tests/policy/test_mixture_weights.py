"""`mixture_weights="demo"`: the action head's mixture weights come from the demonstration summary alone."""

import pytest
import torch

from tests.helpers.policy import HEIGHT, WIDTH, random_batch, small_config


def _gated_policy():
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    return MosaicPolicy(small_config(demo_summary=True, mixture_weights="demo", wrong_demo_loss_weight=1.0))


def test_the_demonstration_alone_sets_the_mixture_weights():
    policy = _gated_policy().eval()
    demos = [torch.rand(policy.config.n_demo_frames, 3, HEIGHT, WIDTH) for _ in range(2)]
    frames = [torch.rand(1, 3, HEIGHT, WIDTH) for _ in range(2)]
    weights, means = {}, {}
    with torch.no_grad():
        for d, demo in enumerate(demos):
            policy.set_demo(demo)
            for f, frame in enumerate(frames):
                distribution = policy.chunk_distribution(frame, None, policy._context)
                weights[d, f], means[d, f] = distribution.logit_probs, distribution.means
    assert weights[0, 0].shape == (1, policy.config.action_chunk * 7, policy.config.n_mixtures)
    assert torch.equal(weights[0, 0], weights[0, 1])  # another frame, the same weights
    assert not torch.equal(weights[0, 0], weights[1, 0])  # another demonstration, other weights
    assert not torch.equal(means[0, 0], means[0, 1])  # the frame still moves the components


def test_training_with_the_wrong_demonstration_loss_gives_the_gate_a_gradient():
    policy = _gated_policy().train()
    batch = random_batch(policy.config, batch_size=4)
    batch["task"] = ["a", "b", "a", "b"]
    loss, info = policy.forward(batch)
    loss.backward()
    assert "wrong_demo_loss" in info
    gate = policy.model.mixture_gate.weight.grad
    assert gate is not None and gate.abs().sum() > 0
    assert torch.isfinite(loss)


def test_demo_weights_without_a_summary_name_the_flag():
    with pytest.raises(ValueError, match="--policy.demo_summary=true"):
        small_config(mixture_weights="demo")
