"""The paper's training augmentations: random translate / resized crop, colour jitter, Gaussian blur.

One random draw per sequence (the frames of one sample share it, so motion stays coherent); two calls give
the two views of the contrastive module. Only ever applied on the training path.
"""

import torch
from torch import Tensor, nn
from torchvision.transforms import v2


class FrameAugmentation(nn.Module):
    def __init__(
        self,
        height: int,
        width: int,
        crop_scale_min: float = 0.8,
        translate_fraction: float = 0.05,
        color_jitter: float = 0.2,
        blur_probability: float = 0.3,
    ):
        super().__init__()
        ratio = width / height
        steps = [
            v2.RandomAffine(degrees=0.0, translate=(translate_fraction, translate_fraction)),
            v2.RandomResizedCrop((height, width), scale=(crop_scale_min, 1.0), ratio=(ratio * 0.9, ratio / 0.9), antialias=True),
        ]
        if color_jitter > 0:
            steps.append(v2.ColorJitter(color_jitter, color_jitter, color_jitter, color_jitter / 4))
        if blur_probability > 0:
            steps.append(v2.RandomApply([v2.GaussianBlur(5, sigma=(0.1, 2.0))], p=blur_probability))
        self.transform = v2.Compose(steps)

    @torch.no_grad()
    def forward(self, frames: Tensor) -> Tensor:
        """frames (B, T, 3, H, W) float in [0, 1] -> same shape, a new random draw per sequence."""
        return torch.stack([self.transform(sequence).clamp(0.0, 1.0) for sequence in frames])
