"""A small strided CNN trunk for training on CPU (``--policy.vision_backbone=conv``), trained from scratch.

Four 3x3 convolutions of stride 2 (32, 64, 128 and `channels` channels, 256 by default), each followed by
BatchNorm and ReLU: images (N, 3, H, W) in [0, 1] -> features (N, channels, H/16, W/16 rounded up). At 256
channels that is exactly the shape of :class:`~mosaic_policy.common.resnet_trunk.ResNetTrunk` for every input
size (a stride-2 3x3 convolution with padding 1 maps n to ceil(n / 2), as ResNet's stem, max-pool and strided
stages do), so every policy's attention, embeddings and keypoints work unchanged. 0.39 M parameters against the ResNet trunk's 2.78 M; on CPU at 48x88
its forward + backward is several times cheaper. The attention, the embedding and the heads work on the trunk's
channels, so fewer of them (``--policy.conv_channels=128``) make the whole model cheaper: at 256 the attention
takes half of a MOSAIC training step (``python -m pipelines.bench.policy_train_step --compare-trunks`` prints the
parts and the step at each width).

Robomimic's small image encoders end with a spatial soft-argmax (keypoints); this one keeps the spatial feature
map, because MOSAIC's and T-OSIL's attention attends over its h x w locations and the embeddings keep where
things are (DAML adds its own soft-argmax on top, as with the ResNet trunk). At 48x88 that map is 3x6, one
location per 16 pixels, where a door handle's place varies by a few centimetres (a pixel or two):
``--policy.conv_keypoints=K`` adds K soft-argmax keypoints of the third layer's finer map (6x11 at 48x88) as 2K
of the `channels`, each the same at every location, so every policy reads them where it reads the features.
"""

import copy

import torch
from torch import Tensor, nn

from .keypoints import SpatialSoftArgmax

WIDTHS = (32, 64, 128)
"""Output channels of the first three stride-2 convolutions; the fourth gives the trunk's `channels`."""

KEYPOINT_LAYER = 3
"""With keypoints: the stride-2 layer whose output (WIDTHS[2] channels, H/8 x W/8) the soft-argmax reads."""

MODULES_PER_LAYER = 3
"""Convolution, BatchNorm, ReLU."""


class ConvTrunk(nn.Module):
    """Images (N, 3, H, W) in [0, 1] -> features (N, channels, H/16, W/16 rounded up); 100x180 -> 256x7x12.

    With ``keypoints`` K > 0 the last convolution gives channels - 2K of them and the K keypoints' x, y fill the
    other 2K (the same value at every location)."""

    channels_last = False

    def __init__(self, channels: int = 256, keypoints: int = 0):
        super().__init__()
        if not 0 <= 2 * keypoints < channels:
            raise ValueError(f"{keypoints} keypoints need {2 * keypoints} of the {channels} channels: use fewer.")
        self.out_channels = channels
        self.n_keypoints = keypoints
        self.keypoints = SpatialSoftArgmax(WIDTHS[KEYPOINT_LAYER - 1], keypoints) if keypoints else None
        layers: list[nn.Module] = []
        in_channels = 3
        for width in (*WIDTHS, channels - 2 * keypoints):
            layers += [
                nn.Conv2d(in_channels, width, 3, stride=2, padding=1, bias=False),
                nn.BatchNorm2d(width),
                nn.ReLU(inplace=True),
            ]
            in_channels = width
        self.layers = nn.Sequential(*layers)

    def forward(self, images: Tensor) -> Tensor:
        x = (images - 0.5) / 0.25  # centre [0, 1] pixels; BatchNorm takes it from there
        if self.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        if self.keypoints is None:
            return self.layers(x)
        split = KEYPOINT_LAYER * MODULES_PER_LAYER
        finer = self.layers[:split](x)
        features = self.layers[split:](finer)
        points = self.keypoints(finer)[:, :, None, None].expand(-1, -1, *features.shape[2:])
        return torch.cat([features, points], dim=1)

    def feature_shape(self, height: int, width: int) -> tuple[int, int, int]:
        """(channels, h, w) of the features for an input of this size: each stride-2 layer rounds up."""
        for _ in range(len(WIDTHS) + 1):
            height, width = (height + 1) // 2, (width + 1) // 2
        return self.out_channels, height, width

    def fused_for_inference(self) -> "ConvTrunk":
        """A copy for inference: BatchNorm folded into the convolutions (eval statistics), channels-last memory.

        Outputs match the eval-mode trunk to float rounding."""
        from torch.nn.utils.fusion import fuse_conv_bn_eval

        fused = copy.deepcopy(self).eval()
        layers = list(fused.layers)
        for i, module in enumerate(layers):
            if isinstance(module, nn.Conv2d):
                layers[i], layers[i + 1] = fuse_conv_bn_eval(module, layers[i + 1]), nn.Identity()
        fused.layers = nn.Sequential(*layers)
        fused.channels_last = True
        for p in fused.parameters():
            p.requires_grad_(False)
        return fused.to(memory_format=torch.channels_last)
