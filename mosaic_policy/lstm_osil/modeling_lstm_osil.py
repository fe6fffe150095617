"""LSTM baseline of the paper's Table I: MOSAIC with its attention module replaced by projectors and an LSTM.

Per frame: ResNet-18 trunk (to layer3; `vision_backbone`) -> linear projector (:class:`FrameEmbedding`, shared
by demonstration and observation frames) -> an LSTM reads the demonstration frames, then the sample's
observation frames in order -> its output at each observation frame, projected to `embed_dim` -> the shared
action head (behaviour cloning) and the inverse-dynamics head. No contrastive module: the row isolates what
attention adds.

The trunk, embedding and heads are those of :class:`~mosaic_policy.common.demo_conditioned_model.DemoConditionedModel`
(the same in every row of the table); this module builds the LSTM and its output projection.
Training and inference follow :mod:`mosaic_policy.common.demo_conditioned_policy`. Acting, `set_demo` runs the
LSTM over the demonstration once and caches its (h, c) state; every query embeds the current frame, keeps it in
a memory of the last `train_obs_frames` query frames and runs the LSTM from the cached state over that memory,
which is what training computes for the last frame of a sample holding the same frames.
"""

from collections import deque

import torch
from torch import Tensor, nn

from ..common.demo_conditioned_model import DemoConditionedModel
from ..common.demo_conditioned_policy import DemoConditionedPolicy, expand_to_batch
from ..common.discretized_logistic import DiscretizedLogisticMixture
from .configuration_lstm_osil import LstmOsilConfig

LstmState = tuple[Tensor, Tensor]
"""(h, c) of an `nn.LSTM`, each (n_lstm_layers, B, lstm_hidden_dim)."""


class LstmOsilModel(DemoConditionedModel):
    """The shared trunk, projector (the frame embedding) and heads; an LSTM and its output projection as the task
    context."""

    def build_context(self, channels: int, height: int, width: int) -> None:
        config = self.config
        self.lstm = nn.LSTM(
            config.embed_dim,
            config.lstm_hidden_dim,
            config.n_lstm_layers,
            batch_first=True,
            dropout=config.lstm_dropout if config.n_lstm_layers > 1 else 0.0,  # nn.LSTM warns on 1 layer
        )
        self.output = nn.Sequential(nn.Linear(config.lstm_hidden_dim, config.embed_dim), nn.ReLU())

    def run_lstm(self, vectors: Tensor, state: LstmState | None = None) -> tuple[Tensor, LstmState]:
        """(B, T, embed_dim) from `state` (zeros when None) -> outputs (B, T, lstm_hidden_dim) and the last state."""
        return self.lstm(vectors, state)

    def observation_embeddings(self, trunk: nn.Module, demo: Tensor, obs: Tensor) -> Tensor:
        """The LSTM reads the demo frames (B, D, 3, H, W), then the observation frames (B, T, 3, H, W); its
        outputs at the observation frames, projected, are their embeddings (B, T, embed_dim)."""
        vectors = self.frame_vectors(trunk, torch.cat([demo, obs], dim=1))
        outputs, _ = self.run_lstm(vectors)
        return self.output(outputs[:, demo.shape[1] :])


class LstmOsilPolicy(DemoConditionedPolicy):
    """The LSTM baseline as a LeRobot policy; see the module docstring."""

    config_class = LstmOsilConfig
    name = "lstm_osil"

    def build(self, image_hw: tuple[int, int], state_dim: int, action_dim: int) -> None:
        self.model = LstmOsilModel(self.config, image_hw, state_dim, action_dim)

    def reset_memory(self) -> None:
        """Forget the episode's query frames: the next query starts a window right after the demonstration."""
        self._memory: deque[Tensor] = deque(maxlen=self.config.train_obs_frames)  # (B, embed_dim) per frame

    # -- inference ------------------------------------------------------------------------------------------

    def encode_demo(self, demo: Tensor) -> LstmState:
        """The LSTM state after reading the demonstration frames (depends on the demonstration only)."""
        model = self.acting_model
        _, state = model.run_lstm(model.frame_vectors(self.trunk_for_inference(), demo))
        return state

    def chunk_distribution(self, image: Tensor, state: Tensor | None, context: LstmState) -> DiscretizedLogisticMixture:
        model = self.acting_model
        vector = model.frame_vectors(self.trunk_for_inference(), image.unsqueeze(1))[:, 0]  # (B, E)
        h, c = expand_to_batch(context, vector.shape[0], dim=1)
        if self._memory and self._memory[-1].shape[0] != vector.shape[0]:
            raise ValueError(
                f"the batch changed from {self._memory[-1].shape[0]} to {vector.shape[0]} environments mid-episode; "
                "call policy.reset() and set_demo() before changing it."
            )
        window = torch.stack([*self._memory, vector], dim=1)[:, -self.config.train_obs_frames :]  # current last
        outputs, _ = model.run_lstm(window, (h.contiguous(), c.contiguous()))
        distribution = model.action_distribution(model.output(outputs[:, -1]), state)
        self._memory.append(vector)  # remembered once the query succeeded: a failed one leaves the episode as it was
        return distribution
