"""The network every demonstration-conditioned policy is built on: trunk, frame embedding and the two heads.

The rows of the paper's Table I differ in how the demonstration conditions the observation frames (the task
context: attention over the feature maps in MOSAIC and T-OSIL, an LSTM or an MLP over frame vectors in the
baselines, weights adapted to the demonstration in DAML). Everything around that is built here, the same way
for every row, so that a comparison measures the task context alone:

- the vision trunk (`vision_backbone`): frames (N, 3, H, W) -> features (N, C, h, w); `feature_shape` is
  (C, h, w);
- the frame embedding (:class:`~.frame_features.FrameEmbedding`): a frame's features -> an `embed_dim` vector;
- the action head: a frame's embedding, and the robot state with `use_state`, -> a discretised logistic
  mixture over the `action_chunk` targets that follow the frame;
- the inverse-dynamics head: the embeddings of two consecutive frames -> the targets from the first on.

A subclass creates its task context in :meth:`build_context` and says in :meth:`observation_embeddings` what
the heads read. A model without a frame embedding or an inverse-dynamics head (DAML's keypoints feed an
adapted network, and DAML has no inverse loss) turns them off with the class attributes below.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from mosaic_data.constants import STATE_NAMES

from .configuration_demo import DemoConditionedConfig
from .discretized_logistic import DiscretizedLogisticHead, DiscretizedLogisticMixture
from .frame_features import FrameEmbedding, trunk_features
from .trunks import make_trunk


def make_action_head(config: DemoConditionedConfig, in_dim: int, action_dim: int) -> DiscretizedLogisticHead:
    """The paper's action head: one discretised logistic mixture per action dimension of every chunk target."""
    return DiscretizedLogisticHead(
        in_dim, action_dim * config.action_chunk, config.n_mixtures, config.head_hidden_dim, config.action_bins
    )


class DemoConditionedModel(nn.Module):
    """Trunk, task context (the subclass's), frame embedding, action head and inverse-dynamics head.

    The modules are created in that order. ``state_dim`` is the width of the dataset's robot state (0 unless
    `use_state`); the action head reads all of it, or the `state_components` the config names."""

    has_frame_embedding = True
    """Build `embed`, the :class:`FrameEmbedding` of a frame's trunk features."""
    has_inverse_head = True
    """Build `inverse_head`, read by the inverse-dynamics loss."""

    def __init__(self, config: DemoConditionedConfig, image_hw: tuple[int, int], state_dim: int, action_dim: int):
        super().__init__()
        self.config = config
        self.state_indices = [STATE_NAMES.index(name) for name in config.state_components]  # empty: the whole state
        self.state_dim = len(self.state_indices) if state_dim and self.state_indices else state_dim  # the head's
        self.trunk = make_trunk(config)
        channels, h, w = self.trunk.feature_shape(*image_hw)
        self.feature_shape = (channels, h, w)
        self.build_context(channels, h, w)
        self.embed = FrameEmbedding(channels, h, w, config.embed_dim) if self.has_frame_embedding else None
        self.action_head = make_action_head(config, config.embed_dim + self.state_dim, action_dim)
        self.inverse_head = None
        if self.has_inverse_head:
            self.inverse_head = make_action_head(config, 2 * config.embed_dim, action_dim)

    def build_context(self, channels: int, height: int, width: int) -> None:
        """Create the modules through which the demonstration conditions the observation frames, given the
        trunk's feature shape (C, h, w)."""
        raise NotImplementedError

    def observation_embeddings(self, trunk: nn.Module, demo: Tensor, obs: Tensor) -> Tensor:
        """(B, T, embed_dim) embeddings of observation frames (B, T, 3, H, W) conditioned on demonstration frames
        (B, D, 3, H, W): what the action and inverse-dynamics heads read. ``trunk`` is the trained one or a
        copy of it (the EMA target, the fused inference trunk)."""
        raise NotImplementedError

    def frame_embeddings(self, features: Tensor) -> Tensor:
        """(B, C, T, h, w) feature maps -> (B, T, embed_dim), every frame on its own."""
        return self.embed.frames(features)

    def frame_vectors(self, trunk: nn.Module, frames: Tensor) -> Tensor:
        """(B, T, 3, H, W) frames -> (B, T, embed_dim) through the trunk and the embedding, every frame on its own
        (no demonstration context)."""
        return self.frame_embeddings(trunk_features(trunk, frames))

    def action_distribution(
        self, embeddings: Tensor, state: Tensor | None, mixture_logits: Tensor | None = None
    ) -> DiscretizedLogisticMixture:
        """The action head on embeddings (B, ..., embed_dim); with `use_state` the state (B, ..., state_dim) is
        appended, else ignored (None allowed). ``mixture_logits`` (B, action_chunk * A, n_mixtures), when given,
        replace the head's own mixture weights for every frame of a sample (weights set by something other than
        the frame, e.g. the demonstration)."""
        distribution = self._head(embeddings, state)
        if mixture_logits is not None:
            logits = distribution.logit_probs
            shape = (logits.shape[0],) + (1,) * (logits.dim() - 3) + logits.shape[-2:]
            distribution.logit_probs = mixture_logits.reshape(shape).expand_as(logits)
        return distribution

    def _head(self, embeddings: Tensor, state: Tensor | None) -> DiscretizedLogisticMixture:
        """The action head's own output on the embeddings (and the state the config names)."""
        if self.state_dim:
            if state is None:
                raise ValueError("use_state is on but the batch has no observation.state.")
            if self.state_indices:
                state = state[..., self.state_indices]
            embeddings = torch.cat([embeddings, state.reshape(*embeddings.shape[:-1], -1)], dim=-1)
        return self.action_head(embeddings)
