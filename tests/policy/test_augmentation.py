"""The batched training augmentation: one draw per sequence, shared by its frames, seeded by torch's stream."""

import torch

from mosaic_policy.common.augmentation import FrameAugmentation


def _frames(batch: int = 6, frames: int = 4, height: int = 24, width: int = 44) -> torch.Tensor:
    torch.manual_seed(0)
    return torch.rand(batch, frames, 3, height, width)


def test_shape_and_range_are_kept():
    x = _frames()
    y = FrameAugmentation(24, 44)(x)
    assert y.shape == x.shape and y.dtype == x.dtype
    assert 0.0 <= float(y.min()) and float(y.max()) <= 1.0


def test_the_frames_of_a_sequence_share_one_draw_and_sequences_differ():
    still = _frames()[:, :1].expand(-1, 5, -1, -1, -1).contiguous()  # every sequence shows one frame 5 times
    y = FrameAugmentation(24, 44)(still)
    assert torch.equal(y, y[:, :1].expand_as(y))  # the same crop, colours and blur on every frame
    assert all(not torch.allclose(y[0], y[i]) for i in range(1, y.shape[0]))


def test_draws_follow_torchs_seed():
    x = _frames()
    augment = FrameAugmentation(24, 44)
    torch.manual_seed(7)
    first = augment(x)
    torch.manual_seed(7)
    assert torch.equal(first, augment(x))
    assert not torch.equal(first, augment(x))  # the next call is a new draw (the contrastive module's second view)


def test_without_jitter_and_blur_a_uniform_image_keeps_its_colour_inside_the_crop():
    grey = torch.full((8, 2, 3, 24, 44), 0.6)
    y = FrameAugmentation(24, 44, color_jitter=0.0, blur_probability=0.0)(grey)
    centre = y[..., 8:16, 15:29]  # the shift is at most 5% of a side: the centre never sees the zero border
    assert torch.allclose(centre, torch.full_like(centre, 0.6), atol=1e-5)


def test_colour_jitter_changes_colours_but_not_geometry_of_a_uniform_image():
    grey = torch.full((8, 1, 3, 24, 44), 0.5)
    y = FrameAugmentation(24, 44, crop_scale_min=1.0, translate_fraction=0.0, blur_probability=0.0)(grey)
    centre = y[..., 4:20, 4:40]
    per_sequence = centre.mean((1, 3, 4))  # (B, 3) colour of each sequence
    assert torch.allclose(centre, per_sequence[:, None, :, None, None].expand_as(centre), atol=1e-5)  # still uniform
    assert per_sequence.std(0).max() > 0.01  # different colours per sequence
