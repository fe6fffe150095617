"""Temporal contrastive representation learning with an EMA target encoder.

Online branch: pooled features of view 1 -> projector -> predictor (query q).
Target branch: pooled features of view 2 from the EMA encoder -> EMA projector (key k, no gradient).
InfoNCE: logits_ij = q_i^T W k_j / tau with a full learnable bilinear W (not only its diagonal, unlike the
original code); the positive of frame i is one frame near it in the other view, every other frame of the
batch is a negative. BYOL: 2 - 2 cos(q_i, k_pos(i)), no negatives.
The target projector is updated by EMA with the encoder (the original code never updated it).
"""

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..common.weight_average import ema_update, frozen_copy


def ema_momentum(step: int, total_steps: int, base_momentum: float) -> float:
    """BYOL's cosine schedule: base_momentum at step 0 rising to 1 at total_steps."""
    progress = min(max(step, 0) / max(total_steps, 1), 1.0)
    return 1.0 - (1.0 - base_momentum) * (math.cos(math.pi * progress) + 1.0) / 2.0


def positive_indices(
    n_sequences: int, n_frames: int, mode: str, window: int, valid: Tensor, generator: torch.Generator | None = None
) -> Tensor:
    """Index (into the flattened (n_sequences * n_frames) frames) of the positive of every frame.

    mode "window": a random valid frame of the same sequence within +-window steps (the frame itself included);
    "fixed": the frame `window` steps later (earlier at the end of the sequence); "same": the frame itself.
    `valid` (n_sequences, n_frames) marks real (not padded) frames; a frame with no valid candidate keeps itself.
    """
    t = torch.arange(n_frames)
    if mode == "same":
        offsets = torch.zeros(n_sequences, n_frames, dtype=torch.long)
    elif mode == "fixed":
        forward = t + window
        target = torch.where(forward < n_frames, forward, t - window).clamp(0, n_frames - 1)
        offsets = (target - t).expand(n_sequences, n_frames).clone()
        ok = valid.gather(1, (t + offsets).clamp(0, n_frames - 1))
        offsets = torch.where(ok, offsets, torch.zeros_like(offsets))
    elif mode == "window":
        cand = torch.arange(-window, window + 1)  # (K,)
        idx = t[:, None] + cand[None, :]  # (T, K)
        in_range = (idx >= 0) & (idx < n_frames)
        ok = in_range[None] & valid[:, idx.clamp(0, n_frames - 1)]  # (S, T, K)
        scores = torch.rand(ok.shape, generator=generator).masked_fill(~ok, -1.0)
        choice = scores.argmax(dim=-1)  # (S, T)
        offsets = torch.where(ok.any(-1), cand[choice], torch.zeros_like(choice))
    else:
        raise ValueError(f"Unknown positive mode {mode!r}.")
    base = torch.arange(n_sequences)[:, None] * n_frames
    return (base + t[None, :] + offsets).reshape(-1)


def _mlp(in_dim: int, hidden_dim: int, out_dim: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(in_dim, hidden_dim), nn.BatchNorm1d(hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, out_dim))


class TemporalContrastiveModule(nn.Module):
    """Projector, predictor and bilinear similarity for one place in the network (before or after attention)."""

    def __init__(self, feature_dim: int, dim: int, hidden_dim: int, objective: str, temperature: float):
        super().__init__()
        self.objective = objective
        self.temperature = temperature
        self.projector = _mlp(feature_dim, hidden_dim, dim)
        self.predictor = _mlp(dim, hidden_dim, dim)
        self.bilinear = nn.Parameter(torch.eye(dim))
        self.target_projector = frozen_copy(self.projector)

    def trainable_parameters(self):
        return [p for n, p in self.named_parameters() if not n.startswith("target_projector.")]

    @torch.no_grad()
    def update_target(self, momentum: float) -> None:
        ema_update(self.target_projector, self.projector, momentum)

    def keys(self, target_features: Tensor) -> Tensor:
        """Target-branch projections of pooled features (N, feature_dim), no gradient."""
        with torch.no_grad():
            return self.target_projector(target_features)

    def loss(self, online_features: Tensor, keys: Tensor, positives: Tensor, valid: Tensor) -> Tensor:
        """Per-frame loss (N,) (zero where not valid).

        online_features: (N, feature_dim) pooled online features of view 1; keys: (N, dim) from `keys()`;
        positives: (N,) index of each frame's positive key; valid: (N,) real frames (padded ones neither
        ask nor answer).
        """
        if valid.sum() < 2:  # BatchNorm needs two frames; nothing to contrast anyway
            return online_features.new_zeros(online_features.shape[0])
        # BatchNorm in the MLPs sees only real frames.
        queries = online_features.new_zeros(online_features.shape[0], keys.shape[1])
        queries[valid] = self.predictor(self.projector(online_features[valid]))
        q = F.normalize(queries, dim=-1)
        k = F.normalize(keys, dim=-1)
        if self.objective == "byol":
            per_frame = 2.0 - 2.0 * (q * k[positives]).sum(-1)
        else:
            logits = (q @ self.bilinear @ k.T) / self.temperature  # (N, N)
            not_key = ~valid[None, :].expand_as(logits).clone()
            not_key[torch.arange(len(positives)), positives] = False  # the positive always counts
            logits = logits.masked_fill(not_key, float("-inf"))
            per_frame = F.cross_entropy(logits, positives, reduction="none")
        return torch.where(valid, per_frame, torch.zeros_like(per_frame))
