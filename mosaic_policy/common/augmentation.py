"""The paper's training augmentations: random translate / resized crop, colour jitter, Gaussian blur.

One random draw per sequence (the frames of one sample share it, so motion stays coherent); two calls give
the two views of the contrastive module. Only ever applied on the training path.

Every step is batched over the whole (B, T) tensor with per-sequence parameters: the translate and the crop are
one affine resampling (`grid_sample`), the colour jitter is a per-sequence gain, blend and 3x3 hue rotation, and
the blur one grouped separable convolution, so the cost does not grow with per-call overhead times B (four
views per step; `python -m pipelines.bench.policy_train_step --compare-trunks` prints its share of a step). The distributions follow
torchvision's `RandomAffine(translate)`, `RandomResizedCrop(scale, ratio)`, `ColorJitter` (in a fixed order:
brightness, contrast, saturation, hue) and `GaussianBlur(5, sigma=(0.1, 2.0))` with reflect padding.
"""

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

_RGB_TO_YIQ = torch.tensor([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])
"""Hue is a rotation of the chroma plane (I, Q) of YIQ, which keeps luma: a 3x3 matrix per sequence."""
_GRAY = (0.299, 0.587, 0.114)  # ITU-R 601 luma, as torchvision's rgb_to_grayscale
_BLUR_TAPS = 5


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
        self.aspect = width / height
        self.crop_scale_min = crop_scale_min
        self.translate_fraction = translate_fraction
        self.color_jitter = color_jitter
        self.blur_probability = blur_probability
        self.register_buffer("yiq", _RGB_TO_YIQ.clone(), persistent=False)
        self.register_buffer("yiq_inverse", torch.linalg.inv(_RGB_TO_YIQ), persistent=False)

    @torch.no_grad()
    def forward(self, frames: Tensor) -> Tensor:
        """frames (B, T, 3, H, W) float in [0, 1] -> same shape, a new random draw per sequence."""
        frames = self._translate_and_crop(frames)
        if self.color_jitter > 0:
            frames = self._jitter_colours(frames)
        if self.blur_probability > 0:
            frames = self._blur(frames)
        return frames.clamp(0.0, 1.0)

    def _uniform(self, batch: int, low: float, high: float, like: Tensor) -> Tensor:
        return torch.rand(batch, device=like.device, dtype=like.dtype) * (high - low) + low

    def _translate_and_crop(self, frames: Tensor) -> Tensor:
        """Shift by up to `translate_fraction` of each side (zeros come in), then crop a box of area fraction in
        [crop_scale_min, 1] and aspect within 0.9-1/0.9 of the image's, resized back to (H, W)."""
        b, t, c, h, w = frames.shape
        area = self._uniform(b, self.crop_scale_min, 1.0, frames)
        log_ratio = self._uniform(b, math.log(0.9), -math.log(0.9), frames)
        width_fraction = (area * log_ratio.exp()).sqrt().clamp(max=1.0)  # of the image's width
        height_fraction = (area / log_ratio.exp()).sqrt().clamp(max=1.0)
        centre_x = (torch.rand_like(area) * 2 - 1) * (1 - width_fraction)  # normalised [-1, 1] coordinates
        centre_y = (torch.rand_like(area) * 2 - 1) * (1 - height_fraction)
        shift_x = (torch.rand_like(area) * 2 - 1) * 2 * self.translate_fraction
        shift_y = (torch.rand_like(area) * 2 - 1) * 2 * self.translate_fraction
        theta = torch.zeros(b, 2, 3, device=frames.device, dtype=frames.dtype)
        theta[:, 0, 0], theta[:, 0, 2] = width_fraction, centre_x - shift_x
        theta[:, 1, 1], theta[:, 1, 2] = height_fraction, centre_y - shift_y
        grid = F.affine_grid(theta, [b, t * c, h, w], align_corners=False)
        warped = F.grid_sample(frames.reshape(b, t * c, h, w), grid, mode="bilinear", padding_mode="zeros",
                               align_corners=False)
        return warped.view(b, t, c, h, w)

    def _jitter_colours(self, frames: Tensor) -> Tensor:
        b = frames.shape[0]
        strength = self.color_jitter
        per_sequence = (b, 1, 1, 1, 1)
        gray_weights = frames.new_tensor(_GRAY).view(1, 1, 3, 1, 1)

        brightness = self._uniform(b, 1 - strength, 1 + strength, frames).view(per_sequence)
        frames = (frames * brightness).clamp(0.0, 1.0)
        contrast = self._uniform(b, 1 - strength, 1 + strength, frames).view(per_sequence)
        mean_gray = (frames * gray_weights).sum(2, keepdim=True).mean((3, 4), keepdim=True)
        frames = (frames * contrast + mean_gray * (1 - contrast)).clamp(0.0, 1.0)
        saturation = self._uniform(b, 1 - strength, 1 + strength, frames).view(per_sequence)
        gray = (frames * gray_weights).sum(2, keepdim=True)
        frames = (frames * saturation + gray * (1 - saturation)).clamp(0.0, 1.0)

        hue = self._uniform(b, -strength / 4, strength / 4, frames) * 2 * math.pi  # a fraction of a turn
        cos, sin = hue.cos(), hue.sin()
        rotation = torch.zeros(b, 3, 3, device=frames.device, dtype=frames.dtype)
        rotation[:, 0, 0] = 1.0
        rotation[:, 1, 1], rotation[:, 1, 2], rotation[:, 2, 1], rotation[:, 2, 2] = cos, -sin, sin, cos
        colour_map = self.yiq_inverse.to(frames.dtype) @ rotation @ self.yiq.to(frames.dtype)  # (B, 3, 3)
        return torch.einsum("bij,btjhw->btihw", colour_map, frames).clamp(0.0, 1.0)

    def _blur(self, frames: Tensor) -> Tensor:
        """With `blur_probability` per sequence, a 5-tap Gaussian of sigma in [0.1, 2]; the others pass unchanged."""
        b, t, c, h, w = frames.shape
        sigma = self._uniform(b, 0.1, 2.0, frames)
        offsets = torch.arange(_BLUR_TAPS, device=frames.device, dtype=frames.dtype) - _BLUR_TAPS // 2
        kernel = torch.exp(-(offsets**2) / (2 * sigma[:, None] ** 2))
        kernel = kernel / kernel.sum(1, keepdim=True)
        identity = (offsets == 0).to(frames.dtype).expand(b, -1)
        blurred = torch.rand(b, device=frames.device) < self.blur_probability
        kernel = torch.where(blurred[:, None], kernel, identity)  # (B, taps)
        channels = kernel.repeat_interleave(t * c, dim=0)  # one kernel per (sequence, frame, colour) channel
        pad = _BLUR_TAPS // 2
        x = F.pad(frames.reshape(1, b * t * c, h, w), (pad, pad, pad, pad), mode="reflect")
        x = F.conv2d(x, channels.view(-1, 1, 1, _BLUR_TAPS), groups=b * t * c)
        x = F.conv2d(x, channels.view(-1, 1, _BLUR_TAPS, 1), groups=b * t * c)
        return x.view(b, t, c, h, w)
