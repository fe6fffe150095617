"""Configuration of T-OSIL, the transformer baseline of the paper's Table I (Dasari & Gupta, CoRL 2020)."""

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig

from ..common.configuration_demo import DemoConditionedConfig


@PreTrainedConfig.register_subclass("tosil")
@dataclass
class TosilConfig(DemoConditionedConfig):
    """T-OSIL: full spatio-temporal self-attention over the demonstration and observation frames.

    The same trunk, augmentations, action head and time scale as MOSAIC (the shared options); what differs is the
    attention pattern and the losses. Every observation frame attends to all demo tokens and to the tokens of the
    earlier observation frames of its sample (causal: never a later frame, so training matches acting, where the
    policy remembers its last `train_obs_frames` query frames). Losses: behaviour cloning, T-OSIL's inverse
    dynamics, and its point-prediction auxiliary loss, no contrastive module.

    Point prediction: the original predicts where the gripper will be in the image; our datasets carry no camera
    calibration, so a spatial soft-argmax over the attended feature map of each frame (keypoints in image
    coordinates) predicts the gripper target `point_horizon` observation frames ahead (the normalised xyz of the
    action then), a localisation signal through the same image-space bottleneck; the default `point_horizon` is
    the end of the sample's window (`train_obs_frames` - 1).
    """

    # Attention layers (2 single-task; 3 multi-task).
    n_attention_layers: int = 2
    # Heads per attention layer.
    n_attention_heads: int = 4
    # Softmax temperature dividing query-key dot products.
    attention_temperature: float = 16.0
    # Dropout on attention outputs.
    attention_dropout: float = 0.1
    # Weight of the point-prediction auxiliary loss.
    point_loss_weight: float = 1.0
    # Observation frames ahead of each frame whose gripper target the point head predicts.
    point_horizon: int = 6

    def __post_init__(self):
        super().__post_init__()
        for name in ("n_attention_layers", "n_attention_heads"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}.")
        if self.attention_temperature <= 0:
            raise ValueError(f"`attention_temperature` must be > 0, got {self.attention_temperature}.")
        if self.point_horizon < 0:
            raise ValueError(f"`point_horizon` must be >= 0, got {self.point_horizon}.")
