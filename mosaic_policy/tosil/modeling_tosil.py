"""T-OSIL: the transformer baseline of the paper's Table I (Dasari & Gupta, CoRL 2020) on MOSAIC's components.

Per frame: ResNet-18 trunk (to layer3; `vision_backbone`) -> + sinusoidal spatio-temporal encoding (demo frames
at times 0..D-1, observation frames at D..D+T-1) -> non-local attention with the full pattern (demo frames
self-attend; observation frame t attends to every demo token and to the tokens of observation frames 0..t, never
a later one) -> per-frame embedding -> discretised logistic mixture over actions (behaviour cloning). Auxiliary
losses: inverse dynamics between consecutive embeddings, and point prediction (a spatial soft-argmax over each
frame's attended feature map regresses the gripper target `point_horizon` frames ahead; see
:class:`TosilConfig`). No contrastive module.

The trunk, embedding and heads are those of :class:`~mosaic_policy.common.demo_conditioned_model.DemoConditionedModel`
(the same in every row of the table); this module builds the full-pattern attention and the point head.
Acting follows :mod:`mosaic_policy.common.demo_conditioned_policy`: `set_demo` caches every layer's demo
keys/values once per episode; each query pushes the current frame's trunk features into a memory of the last
`train_obs_frames` query frames and recomputes the causal attention over them, so the current frame sees what
it would have seen as the last frame of a training sample.
"""

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lerobot.utils.constants import ACTION

from ..common.attention import NonLocalAttentionStack, spatio_temporal_encoding
from ..common.demo_conditioned_model import DemoConditionedModel
from ..common.demo_conditioned_policy import DemoConditionedPolicy, TrainingSample, expand_to_batch, masked_mean
from ..common.discretized_logistic import DiscretizedLogisticMixture
from ..common.frame_features import FrameMemory, trunk_features
from .configuration_tosil import TosilConfig

N_KEYPOINTS = 32
"""Keypoint channels of the point head's soft-argmax (each gives one expected (x, y) in the image)."""

POINT_DIMS = 3
"""The action's first dimensions the point head predicts: the gripper's xyz target."""

DemoCache = list[tuple[Tensor, Tensor]]
"""Each attention layer's demo keys and values, (B, heads, D*h*w, C/heads) each."""


class SpatialSoftArgmax(nn.Module):
    """(N, C, h, w) -> (N, C, 2): per channel, a softmax over the h*w locations, then the expected (x, y).

    Coordinates run from -1 (left / top) to 1 (right / bottom), so a keypoint says where in the image a channel
    fires, differentiably: the image-space bottleneck of T-OSIL's point prediction."""

    def forward(self, features: Tensor) -> Tensor:
        n, c, h, w = features.shape
        weights = torch.softmax(features.flatten(2), dim=-1).reshape(n, c, h, w)
        ys = torch.linspace(-1.0, 1.0, h, device=features.device, dtype=features.dtype)
        xs = torch.linspace(-1.0, 1.0, w, device=features.device, dtype=features.dtype)
        x = (weights.sum(dim=2) * xs).sum(dim=-1)  # marginal over columns
        y = (weights.sum(dim=3) * ys).sum(dim=-1)  # marginal over rows
        return torch.stack([x, y], dim=-1)


class PointHead(nn.Module):
    """Attended feature maps (B, C, T, h, w) -> predicted xyz (B, T, 3): 1x1 conv to keypoint channels,
    spatial soft-argmax, then an MLP over the keypoints' coordinates."""

    def __init__(self, channels: int, hidden_dim: int, n_keypoints: int = N_KEYPOINTS):
        super().__init__()
        self.keypoints = nn.Conv2d(channels, n_keypoints, 1)
        self.soft_argmax = SpatialSoftArgmax()
        self.mlp = nn.Sequential(nn.Linear(2 * n_keypoints, hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, POINT_DIMS))

    def forward(self, features: Tensor) -> Tensor:
        b, _, t = features.shape[:3]
        maps = self.keypoints(features.transpose(1, 2).flatten(0, 1))  # (B*T, K, h, w)
        return self.mlp(self.soft_argmax(maps).flatten(1)).reshape(b, t, POINT_DIMS)


def point_targets(
    actions: Tensor, is_pad: Tensor | None, n_frames: int, frame_stride: int, horizon: int
) -> tuple[Tensor, Tensor]:
    """The point head's targets (B, T, 3) and which exist (B, T).

    Observation frame t's target is the action's xyz at window position (t + horizon) * frame_stride, clamped
    to the last real (unpadded) position of the sample's window: a target past the window's end or past the
    episode's end is the latest gripper target the sample knows, which is where the gripper is heading. A
    sample without any real action has no targets. actions: (B, L, A) normalised, or (B, A) for one frame.
    """
    if actions.dim() == 2:
        actions = actions.unsqueeze(1)
    b, length = actions.shape[:2]
    positions = torch.arange(length, device=actions.device)
    real = torch.ones(b, length, dtype=torch.bool, device=actions.device) if is_pad is None else ~is_pad.reshape(b, length)
    last_real = torch.where(real, positions, -1).max(dim=1).values  # (B,), -1 when none is real
    wanted = (torch.arange(n_frames, device=actions.device) + horizon) * frame_stride  # (T,)
    index = torch.minimum(wanted[None, :], last_real[:, None]).clamp(min=0)  # (B, T)
    targets = actions[:, :, :POINT_DIMS].gather(1, index[:, :, None].expand(-1, -1, POINT_DIMS))
    exists = (last_real >= 0)[:, None].expand(b, n_frames)
    return targets, exists


class TosilModel(DemoConditionedModel):
    """The shared trunk, embedding and heads, full-pattern attention as the task context, and the point head."""

    def __init__(self, config: TosilConfig, image_hw: tuple[int, int], state_dim: int, action_dim: int):
        super().__init__(config, image_hw, state_dim, action_dim)
        channels, h, w = self.feature_shape
        self.point_head = PointHead(channels, config.head_hidden_dim) if config.point_loss_weight > 0 else None
        d, t = config.n_demo_frames, config.train_obs_frames
        self.register_buffer("demo_position", spatio_temporal_encoding(channels, list(range(d)), h, w), persistent=False)
        # Observation frames are told apart by time: a sample's (or the memory's) first frame is at D, the next D+1...
        self.register_buffer(
            "obs_position", spatio_temporal_encoding(channels, list(range(d, d + t)), h, w), persistent=False
        )

    def build_context(self, channels: int, height: int, width: int) -> None:
        config = self.config
        self.attention = NonLocalAttentionStack.from_config(config, channels, "full")

    def obs_position_for(self, n_frames: int) -> Tensor:
        """(C, n_frames, h, w) encodings of observation frames at times D..D+n_frames-1."""
        if n_frames <= self.obs_position.shape[1]:
            return self.obs_position[:, :n_frames]
        c, _, h, w = self.obs_position.shape
        d = self.config.n_demo_frames
        return spatio_temporal_encoding(c, list(range(d, d + n_frames)), h, w).to(self.obs_position)

    def encode_demo(self, trunk: nn.Module, demo: Tensor) -> DemoCache:
        """Every attention layer's demo keys/values for demo frames (B, D, 3, H, W): they depend on the demo only."""
        _, cache = self.attention.encode_demo(trunk_features(trunk, demo) + self.demo_position)
        return cache

    def attend(self, obs_features: Tensor, cache: DemoCache) -> Tensor:
        """Trunk features (B, C, T, h, w) of consecutive observation frames -> attended features, causal in time."""
        cache = expand_to_batch(cache, obs_features.shape[0])
        return self.attention.attend_obs_causal(obs_features + self.obs_position_for(obs_features.shape[2]), cache)

    def encode(self, trunk: nn.Module, demo: Tensor, obs: Tensor) -> Tensor:
        """Attended features (B, C, T, h, w) of observation frames (B, T, 3, H, W) given demo frames (B, D, ...)."""
        both = trunk_features(trunk, torch.cat([demo, obs], dim=1))
        d = demo.shape[1]
        _, cache = self.attention.encode_demo(both[:, :, :d] + self.demo_position)
        return self.attend(both[:, :, d:], cache)

    def observation_embeddings(self, trunk: nn.Module, demo: Tensor, obs: Tensor) -> Tensor:
        return self.frame_embeddings(self.encode(trunk, demo, obs))


class TosilPolicy(DemoConditionedPolicy):
    """T-OSIL as a LeRobot policy; see the module docstring."""

    config_class = TosilConfig
    name = "tosil"

    def build(self, image_hw: tuple[int, int], state_dim: int, action_dim: int) -> None:
        if self.config.point_loss_weight > 0 and action_dim < POINT_DIMS:
            raise ValueError(
                f"point prediction needs the action's first {POINT_DIMS} dims (xyz) but it has {action_dim}; "
                "pass --policy.point_loss_weight=0."
            )
        self.model = TosilModel(self.config, image_hw, state_dim, action_dim)
        self._memory = FrameMemory(self.config.train_obs_frames)

    def reset_memory(self) -> None:
        """Forget the episode's past frames (a new episode or a new demonstration)."""
        self._memory = FrameMemory(self.config.train_obs_frames)

    # -- inference ------------------------------------------------------------------------------------------

    def encode_demo(self, demo: Tensor) -> DemoCache:
        return self.acting_model.encode_demo(self.trunk_for_inference(), demo)

    def chunk_distribution(self, image: Tensor, state: Tensor | None, context: Any) -> DiscretizedLogisticMixture:
        """Remember the current frame, recompute the causal attention over the remembered frames (positions
        D..D+T'-1, current last, as the last frame of a training sample) and read the current frame's output."""
        features = trunk_features(self.trunk_for_inference(), image.unsqueeze(1))  # (B, C, 1, h, w)
        window = self._memory.push(features[:, :, 0])  # (B, C, T', h, w)
        model = self.acting_model
        current = model.attend(window, context)[:, :, -1:]
        embeddings = model.frame_embeddings(current)[:, 0]
        return model.action_distribution(embeddings, state)

    # -- training -------------------------------------------------------------------------------------------

    def compute_loss(self, sample: TrainingSample) -> tuple[Tensor, dict[str, float]]:
        cfg = self.config
        demo, obs = self.views(sample)
        obs_out = self.model.encode(self.model.trunk, demo, obs)  # (B, C, T, h, w)
        per_sample, info = self.imitation_losses(self.model.frame_embeddings(obs_out), sample)
        if self.model.point_head is not None:
            point = self.point_loss(obs_out, sample)
            per_sample = per_sample + cfg.point_loss_weight * point
            info["point_loss"] = point.mean().item()
        return per_sample, info

    def point_loss(self, obs_out: Tensor, sample: TrainingSample) -> Tensor:
        """Per-sample MSE of the predicted xyz, averaged over the real frames whose target exists."""
        t = obs_out.shape[2]
        cfg = self.config
        pad = sample.batch.get(f"{ACTION}_is_pad")
        targets, exists = point_targets(sample.batch[ACTION], pad, t, cfg.frame_stride, cfg.point_horizon)
        predicted = self.model.point_head(obs_out)  # (B, T, 3)
        error = F.mse_loss(predicted, targets.to(predicted.dtype), reduction="none").mean(-1)  # (B, T)
        return masked_mean(error, exists & sample.valid)
