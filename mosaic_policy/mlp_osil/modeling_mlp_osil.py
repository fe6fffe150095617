"""MLP baseline of the paper's Table I: a task context vector from the stacked demonstration features.

Per frame: ResNet-18 trunk (to layer3; `vision_backbone`) -> linear projector (:class:`FrameEmbedding`, shared
by demonstration and observation frames). The `n_demo_frames` demonstration vectors are concatenated and an MLP
maps them to a `context_dim` task context; every observation frame's vector, concatenated with the context and
projected to `embed_dim`, feeds the shared action head (behaviour cloning) and the inverse-dynamics head. No
attention, no memory of past frames and no contrastive module: the row measures a plain conditioning of the same
trunk.

Training and inference follow :mod:`mosaic_policy.common.demo_conditioned_policy`; acting, `set_demo` computes
the context once per episode.
"""

import torch
from torch import Tensor, nn

from ..common.demo_conditioned_policy import DemoConditionedPolicy, TrainingSample, make_action_head
from ..common.discretized_logistic import DiscretizedLogisticMixture
from ..common.frame_features import FrameEmbedding, trunk_features
from ..common.trunks import make_trunk
from .configuration_mlp_osil import MlpOsilConfig


def context_mlp(in_dim: int, n_layers: int, hidden_dim: int, out_dim: int) -> nn.Sequential:
    """`n_layers` hidden Linear + ReLU layers of `hidden_dim`, then a linear to `out_dim` (no activation)."""
    layers: list[nn.Module] = []
    for i in range(n_layers):
        layers += [nn.Linear(in_dim if i == 0 else hidden_dim, hidden_dim), nn.ReLU()]
    layers.append(nn.Linear(hidden_dim, out_dim))
    return nn.Sequential(*layers)


class MlpOsilModel(nn.Module):
    """Trunk, projector, context MLP, fusion layer and heads."""

    def __init__(self, config: MlpOsilConfig, image_hw: tuple[int, int], state_dim: int, action_dim: int):
        super().__init__()
        self.config = config
        self.trunk = make_trunk(config)
        channels, h, w = self.trunk.feature_shape(*image_hw)
        self.feature_shape = (channels, h, w)
        self.embed = FrameEmbedding(channels, h, w, config.embed_dim)
        demo_dim = config.n_demo_frames * config.embed_dim
        self.context = context_mlp(demo_dim, config.n_context_layers, config.context_hidden_dim, config.context_dim)
        self.fuse = nn.Sequential(nn.Linear(config.embed_dim + config.context_dim, config.embed_dim), nn.ReLU())
        self.state_dim = state_dim
        self.action_head = make_action_head(config, config.embed_dim + state_dim, action_dim)
        self.inverse_head = make_action_head(config, 2 * config.embed_dim, action_dim)

    def frame_vectors(self, trunk: nn.Module, frames: Tensor) -> Tensor:
        """(B, T, 3, H, W) -> (B, T, embed_dim): the projector's vector of every frame on its own."""
        return self.embed.frames(trunk_features(trunk, frames))

    def task_context(self, demo_vectors: Tensor) -> Tensor:
        """(B, D, embed_dim) demonstration vectors -> (B, context_dim); the order of the frames matters."""
        return self.context(demo_vectors.flatten(1))

    def fuse_context(self, obs_vectors: Tensor, context: Tensor) -> Tensor:
        """(B, T, embed_dim) observation vectors and (B, context_dim) context -> (B, T, embed_dim) embeddings."""
        context = context[:, None].expand(-1, obs_vectors.shape[1], -1)
        return self.fuse(torch.cat([obs_vectors, context], dim=-1))

    def encode(self, trunk: nn.Module, demo: Tensor, obs: Tensor) -> Tensor:
        """Demo (B, D, 3, H, W) and observation (B, T, 3, H, W) frames -> (B, T, embed_dim) frame embeddings."""
        vectors = self.frame_vectors(trunk, torch.cat([demo, obs], dim=1))
        d = demo.shape[1]
        return self.fuse_context(vectors[:, d:], self.task_context(vectors[:, :d]))

    def action_distribution(self, embeddings: Tensor, state: Tensor | None) -> DiscretizedLogisticMixture:
        if self.state_dim:
            embeddings = torch.cat([embeddings, state], dim=-1)
        return self.action_head(embeddings)


def expand_context(context: Tensor, batch_size: int) -> Tensor:
    """The demonstration's context for an observation batch of `batch_size` (a batch-1 demo is shared)."""
    if context.shape[0] == batch_size:
        return context
    if context.shape[0] != 1:
        raise ValueError(
            f"the demonstration was set for {context.shape[0]} environments but the batch has {batch_size}; "
            "call set_demo with one demonstration per environment or a single one."
        )
    return context.expand(batch_size, -1)


class MlpOsilPolicy(DemoConditionedPolicy):
    """The MLP baseline as a LeRobot policy; see the module docstring."""

    config_class = MlpOsilConfig
    name = "mlp_osil"

    def build(self, image_hw: tuple[int, int], state_dim: int, action_dim: int) -> None:
        self.model = MlpOsilModel(self.config, image_hw, state_dim, action_dim)

    # -- inference ------------------------------------------------------------------------------------------

    def encode_demo(self, demo: Tensor) -> Tensor:
        """The task context (B, context_dim): it depends on the demonstration only."""
        return self.model.task_context(self.model.frame_vectors(self.trunk_for_inference(), demo))

    def chunk_distribution(self, image: Tensor, state: Tensor | None, context: Tensor) -> DiscretizedLogisticMixture:
        vectors = self.model.frame_vectors(self.trunk_for_inference(), image.unsqueeze(1))  # (B, 1, E)
        embeddings = self.model.fuse_context(vectors, expand_context(context, vectors.shape[0]))[:, 0]
        return self.model.action_distribution(embeddings, self.state_for_head(state, embeddings))

    # -- training -------------------------------------------------------------------------------------------

    def compute_loss(self, sample: TrainingSample) -> tuple[Tensor, dict[str, float]]:
        cfg = self.config
        demo, obs = self.views(sample)
        embeddings = self.model.encode(self.model.trunk, demo, obs)  # (B, T, E)
        distribution = self.model.action_distribution(embeddings, self.state_for_head(sample.state, embeddings))
        bc = self.bc_loss(distribution, sample)
        inverse = self.inverse_loss(self.model.inverse_head, embeddings, sample)
        per_sample = cfg.bc_loss_weight * bc + cfg.inverse_loss_weight * inverse
        return per_sample, {"bc_loss": bc.mean().item(), "inverse_loss": inverse.mean().item()}
