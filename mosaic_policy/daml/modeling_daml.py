"""DAML: the policy adapts its weights to the demonstration by gradient descent (Yu et al., RSS 2018).

Per frame: ResNet-18 trunk (to layer3; `vision_backbone`) -> spatial soft-argmax keypoints -> policy MLP
(`n_policy_layers` hidden layers, then the embedding) -> the shared discretised logistic action head. The
demonstrator is another robot, so its video has no actions to imitate: the inner step descends a *learned*
temporal adaptation loss of the policy's own activations on the demo frames, and the outer loss (behaviour
cloning on the agent's frames with the adapted weights) teaches that loss, the initial weights and the inner
learning rates what a useful adaptation is.

The trunk and the action head are those of :class:`~mosaic_policy.common.demo_conditioned_model.DemoConditionedModel`
(the same in every row of the table); the keypoints and the adapted MLP take the frame embedding's place.

What is adapted, and why:

- the policy MLP only. The trunk is shared and meta-learned but never adapted: a per-sample copy of its 2.8M
  weights (and their second-order graph) for every sample of every batch costs far more than the small MLP,
  and DAML itself adapts a small network on top of its features.
- the action head is shared, not adapted: the adaptation loss reads the MLP's activations, never the head's
  output, so its inner gradient is zero and adapting it would only copy it per sample.

The adaptation loss: a stack of temporal 1-D convolutions (`adapt_loss_channels`) over the embeddings of the
`n_demo_frames` demo frames in order; the inner loss is the squared L2 norm of its output per frame, averaged
over the frames. Its gradient reaches the adapted weights through the activations. Each adapted tensor has its
own learned inner learning rate (stored as a log, initialised at `inner_lr`).

Meta-gradient: the inner gradient is taken per sample with `torch.func` (`grad` inside `vmap`); composed under
autograd it keeps its graph, so the outer loss reaches the adaptation loss through second-order terms. With
`first_order=True` the inner gradient is detached: the initial weights and learning rates still learn, but the
adaptation loss network then gets no gradient at all (it stays at its initialisation).

Not in DAML, so left out: the inverse-dynamics loss (`inverse_loss_weight` is unused by this policy) and the
contrastive losses. Acting, `set_demo` computes the adapted weights once per episode; every query then runs the
trunk, the keypoints and the adapted MLP on the current frame.
"""

from __future__ import annotations

import contextlib
import math

import torch
from torch import Tensor, nn
from torch.func import functional_call, grad_and_value, vmap

from ..common.demo_conditioned_model import DemoConditionedModel
from ..common.demo_conditioned_policy import DemoConditionedPolicy, TrainingSample, expand_to_batch
from ..common.discretized_logistic import DiscretizedLogisticMixture
from ..common.frame_features import EMBED_CHANNELS, trunk_features
from ..common.keypoints import SpatialSoftArgmax
from .configuration_daml import DamlConfig

N_KEYPOINTS = EMBED_CHANNELS
"""Keypoints per frame (each an expected (x, y)): as many as the channels other policies keep per location."""

ADAPT_KERNEL = 3
"""Temporal kernel of the adaptation loss's convolutions: neighbouring demo frames (there are only a few)."""

AdaptedWeights = dict[str, Tensor]
"""The adapted policy MLP's tensors by parameter name, each with a leading batch axis (one set per demo)."""


def policy_mlp(in_dim: int, hidden_dim: int, n_hidden: int, out_dim: int) -> nn.Sequential:
    """The adapted layers: `n_hidden` ReLU layers of `hidden_dim`, then a ReLU embedding of `out_dim`.

    He-initialised, so that the keypoints' small differences between frames reach the head at their own scale
    (PyTorch's default initialisation shrinks them layer by layer, and the head would barely tell frames apart
    early in training)."""
    layers: list[nn.Module] = []
    for i in range(n_hidden):
        layers += [nn.Linear(in_dim if i == 0 else hidden_dim, hidden_dim), nn.ReLU()]
    layers += [nn.Linear(hidden_dim, out_dim), nn.ReLU()]
    for layer in layers:
        if isinstance(layer, nn.Linear):
            nn.init.kaiming_normal_(layer.weight, nonlinearity="relu")
            nn.init.zeros_(layer.bias)
    return nn.Sequential(*layers)


class TemporalAdaptationLoss(nn.Module):
    """The learned inner loss of one demo: temporal convolutions over its frames' activations (D, E) -> the
    mean over frames of the squared L2 norm of the output. Sees no action: the demonstrator is another robot."""

    def __init__(self, in_dim: int, channels: int):
        super().__init__()
        pad = ADAPT_KERNEL // 2
        self.net = nn.Sequential(
            nn.Conv1d(in_dim, channels, ADAPT_KERNEL, padding=pad),
            nn.ReLU(),
            nn.Conv1d(channels, channels, ADAPT_KERNEL, padding=pad),
            nn.ReLU(),
            nn.Conv1d(channels, channels, 1),
        )

    def forward(self, activations: Tensor) -> Tensor:
        """(D, E) activations of one demo's frames, in order -> scalar loss (unbatched: it runs inside vmap)."""
        return self.net(activations.T).pow(2).sum(0).mean()


class DamlModel(DemoConditionedModel):
    """The shared trunk and action head; keypoints and the adapted policy MLP in place of the frame embedding, the
    adaptation loss and the inner rates. No inverse-dynamics head (DAML has no inverse loss)."""

    has_frame_embedding = False
    has_inverse_head = False

    def __init__(self, config: DamlConfig, image_hw: tuple[int, int], state_dim: int, action_dim: int):
        super().__init__(config, image_hw, state_dim, action_dim)
        self.adapt_loss = TemporalAdaptationLoss(config.embed_dim, config.adapt_loss_channels)
        self.adapted_names = [name for name, _ in self.policy.named_parameters()]
        # One learned inner learning rate per adapted tensor, kept as a log so it stays positive.
        self.log_inner_lr = nn.Parameter(torch.full((len(self.adapted_names),), math.log(config.inner_lr)))

    def build_context(self, channels: int, height: int, width: int) -> None:
        config = self.config
        self.keypoints = SpatialSoftArgmax(channels, N_KEYPOINTS)
        self.policy = policy_mlp(2 * N_KEYPOINTS, config.policy_hidden_dim, config.n_policy_layers, config.embed_dim)

    def frame_keypoints(self, trunk: nn.Module, frames: Tensor) -> Tensor:
        """(B, T, 3, H, W) -> (B, T, 2K)."""
        features = trunk_features(trunk, frames)  # (B, C, T, h, w)
        b, _, t = features.shape[:3]
        return self.keypoints(features.transpose(1, 2).flatten(0, 1)).reshape(b, t, -1)


class DamlPolicy(DemoConditionedPolicy):
    """DAML as a LeRobot policy; see the module docstring."""

    config_class = DamlConfig
    name = "daml"

    def build(self, image_hw: tuple[int, int], state_dim: int, action_dim: int) -> None:
        self.model = DamlModel(self.config, image_hw, state_dim, action_dim)

    # -- the inner step -------------------------------------------------------------------------------------

    def adapt(self, demo_keypoints: Tensor) -> tuple[AdaptedWeights, Tensor]:
        """Per-sample adapted policy weights from demo keypoints (B, D, 2K), and each sample's inner loss
        before adaptation (B,). The module's own parameters are read, never written."""
        params = dict(self.acting_model.policy.named_parameters())
        step = vmap(self._inner_step, in_dims=(None, 0))  # the first step starts from the shared weights
        adapted, loss_before = step(params, demo_keypoints)
        for _ in range(self.config.inner_steps - 1):
            adapted, _ = vmap(self._inner_step)(adapted, demo_keypoints)
        return adapted, loss_before

    def _inner_step(self, params: dict[str, Tensor], demo_keypoints: Tensor) -> tuple[dict[str, Tensor], Tensor]:
        """One gradient step of one sample's weights on its demo's adaptation loss (runs inside vmap)."""
        # First order: the inner gradient is a constant of the outer loss, so no outer graph is recorded for it
        # (torch.func.grad still differentiates under an outer no_grad: a transform ignores it).
        with torch.no_grad() if self.config.first_order else contextlib.nullcontext():
            grads, loss = grad_and_value(self._adaptation_loss)(params, demo_keypoints)
        model = self.acting_model
        rates = model.log_inner_lr.exp()
        new = {name: params[name] - rates[i] * grads[name] for i, name in enumerate(model.adapted_names)}
        return new, loss

    def _adaptation_loss(self, params: dict[str, Tensor], demo_keypoints: Tensor) -> Tensor:
        """The learned loss of one demo (D, 2K) under the policy weights `params`."""
        model = self.acting_model
        return model.adapt_loss(functional_call(model.policy, params, (demo_keypoints,)))

    def adapted_embeddings(self, adapted: AdaptedWeights, keypoints: Tensor) -> Tensor:
        """(B, T, 2K) keypoints through each sample's adapted MLP -> (B, T, embed_dim)."""
        policy = self.acting_model.policy
        return vmap(lambda p, x: functional_call(policy, p, (x,)))(adapted, keypoints)

    # -- inference ------------------------------------------------------------------------------------------

    def encode_demo(self, demo: Tensor) -> AdaptedWeights:
        """The adapted weights for the episode, one set per demo (B, ...).

        `set_demo` runs this under `torch.no_grad()`: `torch.func.grad` takes its inner gradient regardless
        (a function transform ignores an outer no_grad), and the result carries no graph to keep."""
        keypoints = self.acting_model.frame_keypoints(self.trunk_for_inference(), demo)
        adapted, _ = self.adapt(keypoints)
        return {name: tensor.detach() for name, tensor in adapted.items()}

    def chunk_distribution(
        self, image: Tensor, state: Tensor | None, context: AdaptedWeights
    ) -> DiscretizedLogisticMixture:
        model = self.acting_model
        keypoints = model.frame_keypoints(self.trunk_for_inference(), image.unsqueeze(1))  # (n, 1, 2K)
        adapted = expand_to_batch(context, keypoints.shape[0])
        embeddings = self.adapted_embeddings(adapted, keypoints)[:, 0]
        return model.action_distribution(embeddings, state)

    # -- training -------------------------------------------------------------------------------------------

    def compute_loss(self, sample: TrainingSample) -> tuple[Tensor, dict[str, float]]:
        """Behaviour cloning of every observation frame with the weights adapted to the sample's demo."""
        demo, obs = self.views(sample)
        keypoints = self.model.frame_keypoints(self.model.trunk, torch.cat([demo, obs], dim=1))
        d = demo.shape[1]
        adapted, loss_before = self.adapt(keypoints[:, :d])
        embeddings = self.adapted_embeddings(adapted, keypoints[:, d:])  # (B, T, E)
        bc = self.bc_loss(self.model.action_distribution(embeddings, sample.state), sample)
        info = {
            "bc_loss": bc.mean().item(),
            "adaptation_loss": loss_before.mean().item(),
            "inner_lr": self.model.log_inner_lr.exp().mean().item(),
        }
        return self.config.bc_loss_weight * bc, info
