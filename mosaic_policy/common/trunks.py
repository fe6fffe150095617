"""The vision trunk a policy is built with, chosen by ``--policy.vision_backbone`` (every policy type)."""

from torch import nn

from .configuration_demo import VISION_BACKBONES, DemoConditionedConfig


def make_trunk(config: DemoConditionedConfig) -> nn.Module:
    """A new trunk for ``config.vision_backbone``: "resnet18" (the paper's) or "conv" (small, for CPU training).

    Both map images (N, 3, H, W) in [0, 1] to (N, C, ceil(H/16), ceil(W/16)) features (C: 256, or the conv
    trunk's `conv_channels`) and provide
    ``out_channels``, ``feature_shape(h, w)`` and ``fused_for_inference()``."""
    backbone = config.vision_backbone
    if backbone == "resnet18":
        from .resnet_trunk import ResNetTrunk

        return ResNetTrunk()
    if backbone == "conv":
        from .conv_trunk import ConvTrunk

        return ConvTrunk(config.conv_channels, config.conv_keypoints)
    raise ValueError(f"`vision_backbone` must be one of {VISION_BACKBONES}, got {backbone!r}.")
