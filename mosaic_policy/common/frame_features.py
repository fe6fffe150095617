"""Per-frame features shared by every policy: the trunk over a sequence of frames, and a frame's embedding."""

from torch import Tensor, nn

EMBED_CHANNELS = 32  # channels kept per location before flattening a frame's features into its embedding


def trunk_features(trunk: nn.Module, frames: Tensor) -> Tensor:
    """(B, T, 3, H, W) frames -> (B, C, T, h, w) trunk features, every frame on its own."""
    b, t = frames.shape[:2]
    features = trunk(frames.flatten(0, 1))
    return features.reshape(b, t, *features.shape[1:]).transpose(1, 2)


class FrameEmbedding(nn.Sequential):
    """(N, C, h, w) feature maps -> (N, embed_dim): a 1x1 convolution to EMBED_CHANNELS, flattened, linear, ReLU.

    Keeps where things are in the image (no pooling), which the action's position targets need."""

    def __init__(self, channels: int, height: int, width: int, embed_dim: int):
        super().__init__(
            nn.Conv2d(channels, EMBED_CHANNELS, 1),
            nn.ReLU(),
            nn.Flatten(),
            nn.Linear(EMBED_CHANNELS * height * width, embed_dim),
            nn.ReLU(),
        )

    def frames(self, features: Tensor) -> Tensor:
        """(B, C, T, h, w) -> (B, T, embed_dim)."""
        b, _, t = features.shape[:3]
        return self(features.transpose(1, 2).flatten(0, 1)).reshape(b, t, -1)


class FrameMemory:
    """The trunk features of a policy's last query frames in an episode, for policies that look back in time
    (T-OSIL, the LSTM, MOSAIC's full attention pattern): at most `max_frames`, oldest dropped first.

    Training samples hold `train_obs_frames` frames `frame_stride` steps apart; acting, the policy is queried
    every `action_chunk` steps, so the memory holds the same time span when the two are equal (the default)."""

    def __init__(self, max_frames: int):
        self.max_frames = max_frames
        self._frames: list[Tensor] = []

    def push(self, features: Tensor) -> Tensor:
        """Add (B, C, h, w) features of the current frame; return the memory (B, C, T', h, w), current last."""
        import torch

        self._frames = (self._frames + [features])[-self.max_frames :]
        return torch.stack(self._frames, dim=2)

    def clear(self) -> None:
        self._frames = []

    def __len__(self) -> int:
        return len(self._frames)
