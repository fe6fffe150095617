"""LSTM baseline of the paper's Table I: MOSAIC with its attention module replaced by projectors and an LSTM.

Per frame: ResNet-18 trunk (to layer3; `vision_backbone`) -> linear projector (:class:`FrameEmbedding`, shared
by demonstration and observation frames) -> an LSTM reads the demonstration frames, then the sample's
observation frames in order -> its output at each observation frame, projected to `embed_dim` -> the shared
action head (behaviour cloning) and the inverse-dynamics head. No contrastive module: the row isolates what
attention adds.

Training and inference follow :mod:`mosaic_policy.common.demo_conditioned_policy`. Acting, `set_demo` runs the
LSTM over the demonstration once and caches its (h, c) state; every query embeds the current frame, keeps it in
a memory of the last `train_obs_frames` query frames and runs the LSTM from the cached state over that memory,
which is what training computes for the last frame of a sample holding the same frames.
"""

from collections import deque

import torch
from torch import Tensor, nn

from ..common.demo_conditioned_policy import DemoConditionedPolicy, TrainingSample, make_action_head
from ..common.discretized_logistic import DiscretizedLogisticMixture
from ..common.frame_features import FrameEmbedding, trunk_features
from ..common.trunks import make_trunk
from .configuration_lstm_osil import LstmOsilConfig

LstmState = tuple[Tensor, Tensor]
"""(h, c) of an `nn.LSTM`, each (n_lstm_layers, B, lstm_hidden_dim)."""


class LstmOsilModel(nn.Module):
    """Trunk, projector, LSTM, output projection and heads."""

    def __init__(self, config: LstmOsilConfig, image_hw: tuple[int, int], state_dim: int, action_dim: int):
        super().__init__()
        self.config = config
        self.trunk = make_trunk(config)
        channels, h, w = self.trunk.feature_shape(*image_hw)
        self.feature_shape = (channels, h, w)
        self.embed = FrameEmbedding(channels, h, w, config.embed_dim)
        self.lstm = nn.LSTM(
            config.embed_dim,
            config.lstm_hidden_dim,
            config.n_lstm_layers,
            batch_first=True,
            dropout=config.lstm_dropout if config.n_lstm_layers > 1 else 0.0,  # nn.LSTM warns on 1 layer
        )
        self.output = nn.Sequential(nn.Linear(config.lstm_hidden_dim, config.embed_dim), nn.ReLU())
        self.state_dim = state_dim
        self.action_head = make_action_head(config, config.embed_dim + state_dim, action_dim)
        self.inverse_head = make_action_head(config, 2 * config.embed_dim, action_dim)

    def frame_vectors(self, trunk: nn.Module, frames: Tensor) -> Tensor:
        """(B, T, 3, H, W) -> (B, T, embed_dim): the projector's vector of every frame on its own."""
        return self.embed.frames(trunk_features(trunk, frames))

    def run_lstm(self, vectors: Tensor, state: LstmState | None = None) -> tuple[Tensor, LstmState]:
        """(B, T, embed_dim) from `state` (zeros when None) -> outputs (B, T, lstm_hidden_dim) and the last state."""
        return self.lstm(vectors, state)

    def encode(self, trunk: nn.Module, demo: Tensor, obs: Tensor) -> Tensor:
        """Demo (B, D, 3, H, W) then observation (B, T, 3, H, W) frames -> (B, T, embed_dim) frame embeddings."""
        vectors = self.frame_vectors(trunk, torch.cat([demo, obs], dim=1))
        outputs, _ = self.run_lstm(vectors)
        return self.output(outputs[:, demo.shape[1] :])

    def action_distribution(self, embeddings: Tensor, state: Tensor | None) -> DiscretizedLogisticMixture:
        if self.state_dim:
            embeddings = torch.cat([embeddings, state], dim=-1)
        return self.action_head(embeddings)


def expand_state(state: LstmState, batch_size: int) -> LstmState:
    """The demonstration's LSTM state for an observation batch of `batch_size` (a batch-1 demo is shared)."""
    demo_batch = state[0].shape[1]
    if demo_batch == batch_size:
        return state
    if demo_batch != 1:
        raise ValueError(
            f"the demonstration was set for {demo_batch} environments but the batch has {batch_size}; "
            "call set_demo with one demonstration per environment or a single one."
        )
    h, c = state
    return h.expand(-1, batch_size, -1).contiguous(), c.expand(-1, batch_size, -1).contiguous()


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
        _, state = self.model.run_lstm(self.model.frame_vectors(self.trunk_for_inference(), demo))
        return state

    def chunk_distribution(self, image: Tensor, state: Tensor | None, context: LstmState) -> DiscretizedLogisticMixture:
        vector = self.model.frame_vectors(self.trunk_for_inference(), image.unsqueeze(1))[:, 0]  # (B, E)
        # Inputs are checked before the memory takes the frame: a failed query leaves the episode as it was.
        head_state = self.state_for_head(state, vector)
        demo_state = expand_state(context, vector.shape[0])
        if self._memory and self._memory[-1].shape[0] != vector.shape[0]:
            raise ValueError(
                f"the batch changed from {self._memory[-1].shape[0]} to {vector.shape[0]} environments mid-episode; "
                "call policy.reset() and set_demo() before changing it."
            )
        self._memory.append(vector)
        window = torch.stack(list(self._memory), dim=1)  # (B, T', E), current frame last
        outputs, _ = self.model.run_lstm(window, demo_state)
        embeddings = self.model.output(outputs[:, -1])
        return self.model.action_distribution(embeddings, head_state)

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
