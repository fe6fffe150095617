"""Exponential moving averages of a module's weights: MOSAIC's contrastive target encoder, and the averaged copy of
a whole model that a policy can act with (`weight_average_decay`).

Behaviour cloning at a constant learning rate ends wherever the last minibatches pushed the weights: checkpoints a
few hundred steps apart roll out very differently. An average of the weights over the last steps (Polyak averaging,
as Diffusion Policy and most image-based imitation codebases act with) smooths that noise without lowering the
learning rate, which on a short budget slows learning.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

WARMUP_OFFSET = 10
"""`warmed_up_decay` starts at 1/WARMUP_OFFSET: the first updates nearly copy the online weights."""


def frozen_copy(online: nn.Module) -> nn.Module:
    """A copy of ``online`` that no optimizer trains (its parameters do not require gradients)."""
    target = copy.deepcopy(online)
    for p in target.parameters():
        p.requires_grad_(False)
    return target


@torch.no_grad()
def ema_update(target: nn.Module, online: nn.Module, momentum: float) -> None:
    """target <- momentum * target + (1 - momentum) * online for parameters; buffers (BatchNorm statistics) are
    copied, so the copy normalises as the online model does."""
    for t, o in zip(target.parameters(), online.parameters(), strict=True):
        t.lerp_(o.detach(), 1.0 - momentum)
    for t, o in zip(target.buffers(), online.buffers(), strict=True):
        t.copy_(o)


def warmed_up_decay(updates: int, decay: float) -> float:
    """The averaging decay after ``updates`` earlier updates: min(decay, (1 + n) / (WARMUP_OFFSET + n)).

    Without the warm-up the average of a short run would still hold a large share of the random initial weights
    (at decay 0.995 and 2250 steps, e^-11 of them: negligible, but at 500 steps e^-2.5 = 8%)."""
    return min(decay, (1.0 + updates) / (WARMUP_OFFSET + updates))
