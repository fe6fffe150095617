"""Which variation a demonstration shows, learned from the labels the datasets already carry.

Every training sample is paired with a demonstration of its own variation (the LeRobot task string), so a batch
says which of its demonstrations show the same variation. A supervised contrastive loss (Khosla et al., 2020) on
a projection of each demonstration's attended frames pulls demonstrations of one variation together and pushes
the others apart: the demonstration stream must encode what tells variations apart (on the door, whether the
door swung towards the robot or away from it), which behaviour cloning alone teaches only through the few
actions where push and pull differ. No class count is fixed: it works for any dataset, multi-task or fine-tuned.
"""

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def variation_projector(in_dim: int, hidden_dim: int, out_dim: int) -> nn.Sequential:
    """The projection the loss reads (Linear, ReLU, Linear; no BatchNorm, so a batch of any size works)."""
    return nn.Sequential(nn.Linear(in_dim, hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, out_dim))


def variation_contrastive_loss(projections: Tensor, variations: Sequence[str], temperature: float) -> Tensor:
    """Per-sample supervised contrastive loss (B,) of projections (B, K) labelled by their variation.

    Sample i's loss is the mean over the other samples p of its variation of
    -log(exp(s_ip / t) / sum over every other sample a of exp(s_ia / t)), s the cosine similarity. A sample whose
    variation nothing else in the batch shows has nothing to be pulled to: its loss is 0.
    """
    if projections.shape[0] != len(variations):
        raise ValueError(f"{projections.shape[0]} projections but {len(variations)} variation labels.")
    z = F.normalize(projections, dim=-1)
    logits = (z @ z.T) / temperature
    itself = torch.eye(projections.shape[0], dtype=torch.bool, device=projections.device)
    log_prob = logits - torch.logsumexp(logits.masked_fill(itself, float("-inf")), dim=1, keepdim=True)
    positive = same_variation_pairs(variations, projections.device)
    n_positive = positive.sum(1)
    loss = -(log_prob * positive).sum(1) / n_positive.clamp(min=1)
    return torch.where(n_positive > 0, loss, torch.zeros_like(loss))


def nearest_is_same_variation(projections: Tensor, variations: Sequence[str]) -> float | None:
    """Share of the samples whose most similar other projection shows their variation, among the samples whose
    variation another sample of the batch shows (None if none): 1 when the projections tell the variations apart.
    The loss's own scale depends on the batch (its floor is the log of each sample's number of positives); this
    figure reads the same whatever the batch."""
    positive = same_variation_pairs(variations, projections.device)
    has_positive = positive.any(1)
    if not has_positive.any():
        return None
    z = F.normalize(projections.detach(), dim=-1)
    nearest = (z @ z.T).fill_diagonal_(float("-inf")).argmax(1)
    return positive[torch.arange(len(nearest)), nearest][has_positive].float().mean().item()


def same_variation_pairs(variations: Sequence[str], device: torch.device) -> Tensor:
    """(B, B) bool: sample j shows sample i's variation, j != i."""
    codes = {name: i for i, name in enumerate(dict.fromkeys(variations))}
    labels = torch.tensor([codes[name] for name in variations], device=device)
    return (labels[:, None] == labels[None, :]).fill_diagonal_(False)
