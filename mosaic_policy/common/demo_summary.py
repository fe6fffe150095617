"""An ordered summary of a demonstration: its frame vectors concatenated in time order, then an MLP.

The MLP baseline conditions its observation frames on this vector alone; MOSAIC can add it beside its attention
(`--policy.demo_summary=true`). Attention lets each observation location look up demonstration locations, which
tells where the demonstrated object is; whether the demonstrator pushed or pulled is a change across frames,
which a fixed-order concatenation states outright.
"""

import torch
from torch import Tensor, nn


def context_mlp(in_dim: int, n_layers: int, hidden_dim: int, out_dim: int) -> nn.Sequential:
    """`n_layers` hidden Linear + ReLU layers of `hidden_dim`, then a linear to `out_dim` (no activation)."""
    layers: list[nn.Module] = []
    for i in range(n_layers):
        layers += [nn.Linear(in_dim if i == 0 else hidden_dim, hidden_dim), nn.ReLU()]
    layers.append(nn.Linear(hidden_dim, out_dim))
    return nn.Sequential(*layers)


def fusion_layer(embed_dim: int, context_dim: int) -> nn.Sequential:
    """(…, embed_dim + context_dim) -> (…, embed_dim): a frame's embedding joined with a task context."""
    return nn.Sequential(nn.Linear(embed_dim + context_dim, embed_dim), nn.ReLU())


def fuse_with_context(fuse: nn.Module, frame_vectors: Tensor, context: Tensor) -> Tensor:
    """(B, T, E) frame vectors and (B, K) context -> (B, T, E): the same context joined to every frame."""
    context = context[:, None].expand(-1, frame_vectors.shape[1], -1)
    return fuse(torch.cat([frame_vectors, context], dim=-1))
