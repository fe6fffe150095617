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
from mosaic_policy.mosaic import modeling_mosaic
from mosaic_policy.mosaic.wrong_demonstration import (
    nearest_other_variation_partners,
    other_variation_partners,
    wrong_demonstration_loss,
)


def test_every_sample_is_paired_with_the_next_sample_of_another_variation():
    assert other_variation_partners(["push", "pull", "push", "pull"]).tolist() == [1, 2, 3, 0]
    assert other_variation_partners(["a", "a", "b", "c"]).tolist() == [2, 2, 3, 0]
    assert other_variation_partners(["a", "a", "a"]) is None  # nothing to tell apart
    assert other_variation_partners(["a"]) is None


def test_the_nearest_partner_is_the_most_alike_demonstration_of_another_variation():
    """Buttons 0 and 1 of one machine lie close, button 5 of the other machine far: each button's nearest other
    variation is its neighbour, never its own variation however alike; one variation alone has no partner."""
    vectors = torch.tensor([[1.0, 0.0], [1.0, 0.1], [0.9, 0.3], [0.0, 1.0], [0.1, 1.0]])
    assert nearest_other_variation_partners(vectors, ["b0", "b0", "b1", "b5", "b5"]).tolist() == [2, 2, 1, 2, 2]
    assert nearest_other_variation_partners(vectors * 7.0, ["b0", "b1", "b1", "b5", "b5"]).tolist() == [1, 0, 0, 2, 2]
    assert nearest_other_variation_partners(vectors, ["b0"] * 5) is None
    with pytest.raises(ValueError, match="one per sample"):
        nearest_other_variation_partners(vectors, ["b0", "b1"])


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


def test_the_nearest_partners_come_from_the_attended_demonstrations(monkeypatch):
    """With wrong_demo_partner=nearest the partners are chosen on the frame embeddings of the batch's own attended
    demonstrations, and the loss is logged."""
    seen = []

    def spy(vectors, variations):
        seen.append((vectors.detach().clone(), list(variations)))
        return nearest_other_variation_partners(vectors, variations)

    monkeypatch.setattr(modeling_mosaic, "nearest_other_variation_partners", spy)
    options = dict(augment=False, attention_dropout=0.0, contrastive="off", demo_summary=True, summary_dim=16)
    torch.manual_seed(0)
    policy = MosaicPolicy(small_config(wrong_demo_loss_weight=1.0, wrong_demo_partner="nearest", **options)).train()
    batch = random_batch(policy.config, batch_size=4)
    batch["task"] = ["a", "b", "c", "a"]
    _, info = policy.forward(batch)
    assert 0.0 < info["wrong_demo_loss"] < 10.0
    with torch.no_grad():
        sample = policy.training_sample(batch)
        online = policy.model.encode(policy.model.trunk, policy.model.attention, sample.demo, sample.obs)
        expected = policy.model.frame_embeddings(online["demo_post"]).flatten(1)
    (vectors, variations), = seen
    assert variations == batch["task"]
    torch.testing.assert_close(vectors, expected)


def test_a_negative_weight_or_an_unknown_partner_names_the_fix():
    with pytest.raises(ValueError, match="wrong_demo_loss_weight` must be >= 0"):
        small_config(wrong_demo_loss_weight=-1.0)
    with pytest.raises(ValueError, match="--policy.wrong_demo_partner=next"):
        small_config(wrong_demo_partner="hardest")
