"""Spatial soft-argmax keypoints: where in the image learned feature maps fire, as coordinates.

A 1x1 convolution makes K maps from a feature map, a softmax over each map's locations turns it into a
distribution, and its expected (x, y) is one keypoint in [-1, 1] (left/top to right/bottom). The expectation
interpolates between locations, so a keypoint is finer than the map's grid: a coarse feature map keeps exact
positions this way (Levine et al., 2016; robomimic's image encoders end with it).
"""

import torch
from torch import Tensor, nn


class SpatialSoftArgmax(nn.Module):
    """(N, C, h, w) features -> (N, 2K) keypoints: x, y of each of the K maps, in [-1, 1]; any h, w."""

    def __init__(self, channels: int, n_keypoints: int):
        super().__init__()
        self.conv = nn.Conv2d(channels, n_keypoints, 1, bias=False)  # a softmax ignores a per-map shift

    def forward(self, features: Tensor) -> Tensor:
        h, w = features.shape[-2:]
        attention = self.conv(features).flatten(2).softmax(dim=-1)  # (N, K, h*w)
        ys, xs = torch.meshgrid(
            torch.linspace(-1, 1, h, device=features.device, dtype=attention.dtype),
            torch.linspace(-1, 1, w, device=features.device, dtype=attention.dtype),
            indexing="ij",
        )
        grid = torch.stack([xs.flatten(), ys.flatten()], dim=-1)  # (h*w, 2)
        return (attention @ grid).flatten(1)  # (N, K * 2): x, y of each keypoint
