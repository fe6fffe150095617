"""MOSAIC's wrong-demonstration loss (--policy.wrong_demo_loss_weight): which partner each sample is compared
with, the loss of known likelihoods, and, in a real forward pass, that the wrong likelihoods are those of the
same batch given the partners' demonstrations."""

from __future__ import annotations

import math

import pytest
import torch
from tests.helpers.policy import random_batch, small_config

from mosaic_policy.common.demo_conditioned_policy import chunk_nll
from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy
from mosaic_policy.mosaic.wrong_demonstration import other_variation_partners, wrong_demonstration_loss


def test_every_sample_is_paired_with_the_next_sample_of_another_variation():
    assert other_variation_partners(["push", "pull", "push", "pull"]).tolist() == [1, 2, 3, 0]
    assert other_variation_partners(["a", "a", "b", "c"]).tolist() == [2, 2, 3, 0]
    assert other_variation_partners(["a", "a", "a"]) is None  # nothing to tell apart
    assert other_variation_partners(["a"]) is None


def test_the_loss_of_known_likelihoods():
    """softplus(right - wrong) per frame, averaged over the valid frames: 0 nats apart is log 2; the right
    demonstration 10 nats likelier is log(1 + e^-10); a frame without actions does not count."""
    right = torch.tensor([[5.0, 0.0, 99.0], [3.0, 3.0, 3.0]])
    wrong = torch.tensor([[5.0, 10.0, 0.0], [3.0, 3.0, 3.0]])
    valid = torch.tensor([[True, True, False], [False, False, False]])
    loss = wrong_demonstration_loss(right, wrong, valid)
    assert loss[0].item() == pytest.approx((math.log(2) + math.log1p(math.exp(-10))) / 2)
    assert loss[1].item() == 0.0


def _frame_nll(policy: MosaicPolicy, batch: dict) -> torch.Tensor:
    """(B, T) NLL of every frame's recorded chunk, from the policy's own encoding of ``batch``."""
    sample = policy.training_sample(batch)
    online = policy.model.encode(policy.model.trunk, policy.model.attention, sample.demo, sample.obs)
    distribution = policy.model.action_distribution(policy.model.embeddings_of(online), sample.state)
    return (chunk_nll(distribution, sample.chunks) * sample.chunk_valid).sum(-1), sample.chunk_valid.any(-1)


@pytest.mark.parametrize("attention_pattern", ["mosaic", "full"])
def test_the_wrong_likelihoods_are_the_batchs_own_given_the_partners_demonstrations(attention_pattern):
    """The logged loss equals the loss recomputed from two plain forward passes, the batch as it is and the batch
    with each sample's demonstration replaced by its partner's (dropout, augmentation and the other losses off so
    that both passes are deterministic), after the loss alone has trained the policy until the demonstrations
    change the likelihoods (at the start they are all log 2, whatever the partners); off by default and with weight
    0 nothing is logged; its gradient reaches the attention and the summary."""
    options = dict(
        attention_pattern=attention_pattern, demo_summary=True, summary_hidden_dim=32, summary_dim=16, augment=False,
        attention_dropout=0.0, contrastive="off", bc_loss_weight=0.0, inverse_loss_weight=0.0,
    )
    torch.manual_seed(0)
    policy = MosaicPolicy(small_config(wrong_demo_loss_weight=1.0, **options)).train()
    batch = random_batch(policy.config, batch_size=4)
    batch["task"] = ["push", "pull", "push", "pull"]  # the partners a permutation: the trunk's BatchNorm statistics stay
    optimizer = torch.optim.Adam(policy.parameters(), lr=1e-3)
    losses = []
    for _ in range(25):  # until the demonstrations change the likelihoods: a wrong partner would show
        loss, info = policy.forward(batch)
        losses.append(info["wrong_demo_loss"])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert losses[-1] < 0.5 * math.log(2), losses
    optimizer.zero_grad()
    loss, info = policy.forward(batch)

    partners = other_variation_partners(batch["task"])
    assert partners.tolist() == [1, 2, 3, 0]
    with torch.no_grad():
        right, valid = _frame_nll(policy, batch)
        wrong, _ = _frame_nll(policy, batch | {"demo_frames": batch["demo_frames"][partners]})
    expected = wrong_demonstration_loss(right, wrong, valid).mean()
    assert info["wrong_demo_loss"] == pytest.approx(expected.item(), abs=1e-3)

    loss.backward()
    for prefix in ("attention", "summary"):
        gradient = sum(p.grad.abs().sum() for n, p in policy.model.named_parameters() if n.startswith(prefix) and p.grad is not None)
        assert gradient > 0, prefix

    for config in (small_config(**options), small_config(wrong_demo_loss_weight=0.0, **options)):
        assert "wrong_demo_loss" not in MosaicPolicy(config).train().forward(batch)[1]
    batch["task"] = ["push"] * 4  # one variation: no partner, nothing logged
    assert "wrong_demo_loss" not in policy.forward(batch)[1]


def test_a_negative_weight_names_the_fix():
    with pytest.raises(ValueError, match="wrong_demo_loss_weight` must be >= 0"):
        small_config(wrong_demo_loss_weight=-1.0)
