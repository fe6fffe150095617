"""Configuration of the LSTM baseline of the paper's Table I."""

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig

from ..common.configuration_demo import DemoConditionedConfig


@PreTrainedConfig.register_subclass("lstm_osil")
@dataclass
class LstmOsilConfig(DemoConditionedConfig):
    """MOSAIC with its attention module replaced by linear projectors and an LSTM of comparable parameter count.

    Every frame's trunk features are projected to a vector (a 1x1 convolution, flattened, linear); the LSTM reads
    the demonstration frames, then the observation frames of the sample in order, and its output at each
    observation frame feeds the shared action head and the inverse-dynamics head. Acting, the LSTM state after
    the demonstration is cached once per episode and the LSTM is run over the last `train_obs_frames` query
    frames (the span a training sample covers). Losses: behaviour cloning and inverse dynamics. Two LSTM layers
    (single-task) have about the parameters of MOSAIC's two attention layers; the LSTM's output is projected to
    `embed_dim`.
    """

    # Stacked LSTM layers (2 single-task, 3 multi-task).
    n_lstm_layers: int = 2
    # Hidden size of each LSTM layer.
    lstm_hidden_dim: int = 256
    # Dropout between LSTM layers.
    lstm_dropout: float = 0.1

    def __post_init__(self):
        super().__post_init__()
        for name in ("n_lstm_layers", "lstm_hidden_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}.")
