"""MLP baseline of the paper's Table I: a task context vector from the stacked demonstration features.

Per frame: ResNet-18 trunk (to layer3; `vision_backbone`) -> linear projector (:class:`FrameEmbedding`, shared
by demonstration and observation frames). The `n_demo_frames` demonstration vectors are concatenated and an MLP
maps them to a `context_dim` task context; every observation frame's vector, concatenated with the context and
projected to `embed_dim`, feeds the shared action head (behaviour cloning) and the inverse-dynamics head. No
attention, no memory of past frames and no contrastive module: the row measures a plain conditioning of the same
trunk.

The trunk, embedding and heads are those of :class:`~mosaic_policy.common.demo_conditioned_model.DemoConditionedModel`
(the same in every row of the table); this module builds the context MLP and the fusion layer.
Training and inference follow :mod:`mosaic_policy.common.demo_conditioned_policy`; acting, `set_demo` computes
the context once per episode.
"""

import torch
from torch import Tensor, nn

from ..common.demo_conditioned_model import DemoConditionedModel
from ..common.demo_conditioned_policy import DemoConditionedPolicy, expand_to_batch
from ..common.demo_summary import context_mlp, fuse_with_context, fusion_layer
from ..common.discretized_logistic import DiscretizedLogisticMixture
from .configuration_mlp_osil import MlpOsilConfig


class MlpOsilModel(DemoConditionedModel):
    """The shared trunk, projector (the frame embedding) and heads; the context MLP and the fusion layer as the
    task context."""

    def build_context(self, channels: int, height: int, width: int) -> None:
        config = self.config
        demo_dim = config.n_demo_frames * config.embed_dim
        self.context = context_mlp(demo_dim, config.n_context_layers, config.context_hidden_dim, config.context_dim)
        self.fuse = fusion_layer(config.embed_dim, config.context_dim)

    def task_context(self, demo_vectors: Tensor) -> Tensor:
        """(B, D, embed_dim) demonstration vectors -> (B, context_dim); the order of the frames matters."""
        return self.context(demo_vectors.flatten(1))

    def fuse_context(self, obs_vectors: Tensor, context: Tensor) -> Tensor:
        """(B, T, embed_dim) observation vectors and (B, context_dim) context -> (B, T, embed_dim) embeddings."""
        return fuse_with_context(self.fuse, obs_vectors, context)

    def observation_embeddings(self, trunk: nn.Module, demo: Tensor, obs: Tensor) -> Tensor:
        """Demo (B, D, 3, H, W) and observation (B, T, 3, H, W) frames -> (B, T, embed_dim): each observation
        frame's vector fused with the demonstration's context."""
        vectors = self.frame_vectors(trunk, torch.cat([demo, obs], dim=1))
        d = demo.shape[1]
        return self.fuse_context(vectors[:, d:], self.task_context(vectors[:, :d]))


class MlpOsilPolicy(DemoConditionedPolicy):
    """The MLP baseline as a LeRobot policy; see the module docstring."""

    config_class = MlpOsilConfig
    name = "mlp_osil"

    def build(self, image_hw: tuple[int, int], state_dim: int, action_dim: int) -> None:
        self.model = MlpOsilModel(self.config, image_hw, state_dim, action_dim)

    # -- inference ------------------------------------------------------------------------------------------

    def encode_demo(self, demo: Tensor) -> Tensor:
        """The task context (B, context_dim): it depends on the demonstration only."""
        model = self.acting_model
        return model.task_context(model.frame_vectors(self.trunk_for_inference(), demo))

    def chunk_distribution(self, image: Tensor, state: Tensor | None, context: Tensor) -> DiscretizedLogisticMixture:
        model = self.acting_model
        vectors = model.frame_vectors(self.trunk_for_inference(), image.unsqueeze(1))  # (B, 1, E)
        embeddings = model.fuse_context(vectors, expand_to_batch(context, vectors.shape[0]))[:, 0]
        return model.action_distribution(embeddings, state)
