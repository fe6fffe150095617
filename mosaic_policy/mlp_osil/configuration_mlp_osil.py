"""Configuration of the MLP baseline of the paper's Table I."""

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig

from ..common.configuration_demo import DemoConditionedConfig


@PreTrainedConfig.register_subclass("mlp_osil")
@dataclass
class MlpOsilConfig(DemoConditionedConfig):
    """An MLP turns the stacked demonstration features into a task context vector, concatenated with each
    observation frame's features for the shared action head.

    Frames are projected to vectors as in the LSTM baseline; the `n_demo_frames` demo vectors are concatenated
    and an MLP of `n_context_layers` hidden layers maps them to a `context_dim` vector (computed once per episode
    when acting). Losses: behaviour cloning and inverse dynamics.
    """

    # Hidden layers of the context MLP (2 single-task, 3 multi-task).
    n_context_layers: int = 2
    # Width of the context MLP's hidden layers.
    context_hidden_dim: int = 512
    # Size of the task context vector.
    context_dim: int = 256

    def __post_init__(self):
        super().__post_init__()
        for name in ("n_context_layers", "context_hidden_dim", "context_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}.")
