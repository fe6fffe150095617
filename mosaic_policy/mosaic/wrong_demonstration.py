"""Actions that a wrong demonstration must not explain: a loss that makes the action head read the demonstration.

A policy can separate demonstrations of different variations in its demonstration stream and still act the same
whatever it is shown: along an expert's trajectory the observation frame alone tells most of what comes next, so
behaviour cloning rewards reading the demonstration only on the few frames where nothing in view tells the
variations apart (the first steps, before the arm heads anywhere). This loss asks, for every observation frame,
which of two demonstrations explains the recorded actions: the sample's own or one of another variation from the
same batch. Per frame it is softplus(NLL_right - NLL_wrong) = -log sigmoid(NLL_wrong - NLL_right), the
cross-entropy of choosing the right one by the actions' likelihoods. It is near zero once the right demonstration
makes the actions a few nats more likely than the wrong one, so it only acts where the demonstration does not yet
change the action; at evaluation the demonstration always matches, so what the policy does with a wrong one
matters only through this gradient.

Which wrong demonstration: the next sample of another variation in the batch ("next"), or the one whose
demonstration the model finds most alike ("nearest", by the cosine of the attended demonstration's frame
embeddings). A partner taken in batch order is often a variation far from the sample's (the other press_button
machine), whose likelihoods a small shift of the target already separates; the nearest one is meant to be the
variation the policy confuses (the neighbouring button). Compared only with it, the policy never learns the coarse
difference: on press_button "nearest" is a measured loss (docs/cpu_learning.md).
"""

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from ..common.demo_conditioned_policy import masked_mean
from .variation_contrastive import same_variation_pairs


def other_variation_partners(variations: Sequence[str]) -> Tensor | None:
    """(B,) index of a sample of another variation for every sample: the next one in the batch (cyclically) whose
    variation differs. None when one variation fills the batch, or some sample has no partner."""
    b = len(variations)
    partners = []
    for i in range(b):
        partner = next((j % b for j in range(i + 1, i + b) if variations[j % b] != variations[i]), None)
        if partner is None:
            return None
        partners.append(partner)
    return torch.tensor(partners, dtype=torch.long)


def nearest_other_variation_partners(vectors: Tensor, variations: Sequence[str]) -> Tensor | None:
    """(B,) index, for every sample, of the sample of another variation whose vector (B, D) has the largest cosine
    with its own. None when some sample has no partner (one variation fills the batch)."""
    if len(variations) != vectors.shape[0]:
        raise ValueError(f"{vectors.shape[0]} vectors but {len(variations)} variations: one per sample.")
    same = same_variation_pairs(variations, vectors.device).fill_diagonal_(True)
    if same.all(dim=1).any():
        return None
    unit = F.normalize(vectors.detach().float(), dim=-1)
    return (unit @ unit.T).masked_fill(same, float("-inf")).argmax(dim=1)


def wrong_demonstration_loss(nll_right: Tensor, nll_wrong: Tensor, valid: Tensor) -> Tensor:
    """Per-sample loss (B,): the mean over valid frames of softplus(nll_right - nll_wrong), both (B, T) negative
    log-likelihoods of a frame's recorded action chunk, with the sample's demonstration and with another
    variation's; ``valid`` (B, T) marks the frames that have actions."""
    return masked_mean(F.softplus(nll_right - nll_wrong), valid)
