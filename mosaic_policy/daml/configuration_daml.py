"""Configuration of DAML, the meta-learning baseline of the paper's Table I (Yu et al., RSS 2018)."""

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig

from ..common.configuration_demo import DemoConditionedConfig


@PreTrainedConfig.register_subclass("daml")
@dataclass
class DamlConfig(DemoConditionedConfig):
    """Domain-adaptive meta-learning: the policy adapts its weights to the demonstration by gradient descent.

    Inner step (per sample, with `torch.func`): the adapted layers take `inner_steps` gradient steps on a learned
    temporal adaptation loss computed on the demonstrator's video alone (no demonstrator actions: another robot);
    outer loss: behaviour cloning of the adapted policy on the agent's frames, back-propagated through the inner
    step into the initial weights, the adaptation loss and the inner learning rates. The policy has the shared
    trunk and action head; frames become keypoints (spatial soft-argmax) and pass through an MLP of
    `n_policy_layers` hidden layers, the layers the inner step adapts (with the action head). Acting, the adapted
    weights are computed once per episode by `set_demo`.
    """

    # Hidden layers of the policy MLP, adapted by the inner step (2 single-task, 3 multi-task).
    n_policy_layers: int = 2
    # Width of the policy MLP's hidden layers (1024: trainable parameters comparable to MOSAIC's, ~4.4M vs ~5.6M).
    policy_hidden_dim: int = 1024
    # Gradient steps of the inner adaptation on the demonstration.
    inner_steps: int = 1
    # Initial inner learning rate (learned per adapted tensor, as in the paper's code).
    inner_lr: float = 0.01
    # Channels of the learned temporal adaptation loss's convolutions.
    adapt_loss_channels: int = 64
    # Skip the second-order terms of the meta-gradient (cheaper, less faithful).
    first_order: bool = False

    def __post_init__(self):
        super().__post_init__()
        for name in ("n_policy_layers", "policy_hidden_dim", "inner_steps", "adapt_loss_channels"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}.")
        if self.inner_lr <= 0:
            raise ValueError(f"`inner_lr` must be > 0, got {self.inner_lr}.")
