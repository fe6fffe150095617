"""The LeRobot policy interface every demonstration-conditioned policy shares; each policy supplies its model.

Training (lerobot-train): a batch holds `train_obs_frames` agent frames per sample, `frame_stride` frames apart,
and the 20 Hz actions of the whole window; every frame predicts the `action_chunk` targets that follow it. The
demonstrator frames and the loss weights come from :class:`~.demo_conditioning.DemoConditioning`. A subclass
implements :meth:`build` (its model, a :class:`~.demo_conditioned_model.DemoConditionedModel`),
:meth:`encode_demo` (what it keeps of a demonstration for a whole episode) and :meth:`chunk_distribution` (the
action distribution of the current frame); :meth:`compute_loss` (per-sample losses of a
:class:`TrainingSample`) is behaviour cloning plus inverse dynamics on the model's observation embeddings, and
a policy with losses of its own overrides it.

Inference: `policy.reset()` then `policy.set_demo(video)` once per episode (the policy encodes and caches what
it can), then `select_action(batch)` every control step: the policy runs once per `action_chunk` steps and hands
out the predicted targets in order. Subclasses act through :attr:`acting_model`: with `weight_average_decay` an
average of the weights over training, else the trained model. An environment can deliver the demonstration as the observation
`observation.demo` (what `lerobot-eval --env.type=mosaic` does): the first `select_action` after `reset()`
caches it.

Multi-process training (``accelerate launch ... lerobot-train``, docs/multi_gpu_training.md): every process pairs
the samples of its own shard, draws its own augmentations from the first training step on, balances the loss
over the global batch, and :meth:`update` averages the BatchNorm statistics over the processes after every
optimizer step (:mod:`.distributed`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor, nn

from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_STATE

from mosaic_data.constants import DEMO_FRAMES_KEY, OBS_DEMO_KEY

from .augmentation import FrameAugmentation
from .configuration_demo import DemoConditionedConfig
from .demo_conditioning import DemoConditioning, to_float_frames
from .discretized_logistic import DiscretizedLogisticMixture
from .distributed import average_batchnorm_statistics, rank_random_generators
from .hand_relative import HandRelativeTargets, check_state_names, dataset_offset_stats
from .paired_sampling import demo_frame_indices
from .weight_average import ema_update, frozen_copy, warmed_up_decay

if TYPE_CHECKING:
    from huggingface_hub import ModelCard
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.datasets import LeRobotDatasetMetadata


@dataclass
class TrainingSample:
    """One training batch in the shapes every policy's loss reads."""

    obs: Tensor  # (B, T, 3, H, W) float in [0, 1], un-augmented
    demo: Tensor  # (B, D, 3, H, W) float in [0, 1], un-augmented
    chunks: Tensor  # (B, T, action_chunk, A) normalised targets that follow each frame (hand_relative_targets: offsets)
    chunk_valid: Tensor  # (B, T, action_chunk) real targets of real frames
    valid: Tensor  # (B, T) real observation frames (not padding past the episode's end)
    state: Tensor | None  # (B, T, state_dim) or None
    batch: dict[str, Any]


def chunk_nll(distribution: DiscretizedLogisticMixture, chunks: Tensor) -> Tensor:
    """Negative log-likelihood per target (B, T, chunk), summed over action dimensions."""
    flat = chunks.flatten(-2)  # (B, T, chunk * A), the head's layout
    return -distribution.log_prob(flat).reshape(chunks.shape).sum(-1)


def masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean over the last axis of the entries where mask is true (0 where none is)."""
    mask = mask.to(values.dtype)
    return (values * mask).sum(-1) / mask.sum(-1).clamp(min=1.0)


def expand_to_batch(context: Any, batch_size: int, dim: int = 0) -> Any:
    """What a policy keeps of the demonstration (a tensor, or a list, tuple or dict of them, batch axis ``dim``)
    for ``batch_size`` environments: as it is when set per environment, else one demonstration shared by all
    (its size-1 batch axis expanded, without a copy)."""
    if isinstance(context, Tensor):
        n = context.shape[dim]
        if n == batch_size:
            return context
        if n != 1:
            raise ValueError(
                f"the demonstration was set for {n} environments but the batch has {batch_size}: call set_demo with "
                "one demonstration per environment, or a single one for all."
            )
        shape = list(context.shape)
        shape[dim] = batch_size
        return context.expand(shape)
    if isinstance(context, dict):
        return {key: expand_to_batch(value, batch_size, dim) for key, value in context.items()}
    return type(context)(expand_to_batch(value, batch_size, dim) for value in context)


class DemoConditionedPolicy(PreTrainedPolicy):
    """Shared interface; see the module docstring. Subclasses set ``config_class`` and ``name``."""

    config_class = DemoConditionedConfig
    name = "demo_conditioned"

    def __init__(self, config: DemoConditionedConfig, dataset_meta=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config = config
        self.camera_key = config.camera_key
        image_shape = tuple(config.image_features[self.camera_key].shape)  # (3, H, W)
        self.image_hw = (int(image_shape[-2]), int(image_shape[-1]))
        state = config.robot_state_feature
        self.state_dim = int(state.shape[0]) if state is not None else 0
        if config.use_state and state is None:
            raise ValueError("`use_state` is on but the dataset has no observation.state; pass --policy.use_state=false.")
        self.action_dim = int(config.action_feature.shape[0])
        self.augment = FrameAugmentation(
            *self.image_hw,
            crop_scale_min=config.crop_scale_min,
            translate_fraction=config.translate_fraction,
            color_jitter=config.color_jitter,
            blur_probability=config.blur_probability,
        )
        self.build(self.image_hw, self.state_dim if config.use_state else 0, self.action_dim)
        # The weights averaged over training (`weight_average_decay`); update() moves them after every step.
        self.averaged_model = frozen_copy(self.model) if config.weight_average_decay is not None else None
        if self.averaged_model is not None:
            self.register_buffer("weight_average_updates", torch.zeros((), dtype=torch.long))
        self.hand_relative = self._hand_relative_targets(dataset_meta, kwargs.get("agent_episodes"))
        if dataset_meta is not None:
            self.conditioning = DemoConditioning.for_training(config, dataset_meta, kwargs.get("agent_episodes"))
        else:
            self.conditioning = DemoConditioning(None, config.balance_loss)
        self._rank_streams = False  # set once this process has its own random stream (multi-process training)
        self.reset()

    def _hand_relative_targets(self, dataset_meta, episodes: list[int] | None) -> HandRelativeTargets | None:
        """With `hand_relative_targets`: the converter, fitted to the training dataset (a loaded policy's comes from
        its checkpoint)."""
        if not self.config.hand_relative_targets:
            return None
        if self.config.robot_state_feature is None:
            raise ValueError(
                "`hand_relative_targets` needs observation.state (the hand position): train on a dataset that has it "
                "or pass --policy.hand_relative_targets=false."
            )
        converter = HandRelativeTargets()
        if dataset_meta is not None:
            check_state_names(dataset_meta.features.get(OBS_STATE, {}).get("names"))
            offsets = dataset_offset_stats(dataset_meta.root, dataset_meta.features, self.config.action_chunk, episodes)
            converter.fit(dataset_meta.stats, offsets)
        return converter

    # -- what a policy supplies ----------------------------------------------------------------------------

    def build(self, image_hw: tuple[int, int], state_dim: int, action_dim: int) -> None:
        """Create the policy's modules; ``state_dim`` is 0 unless the action head reads the state."""
        raise NotImplementedError

    def compute_loss(self, sample: TrainingSample) -> tuple[Tensor, dict[str, float]]:
        """Per-sample losses (B,) of a training batch, and figures to log: behaviour cloning and inverse dynamics
        of the model's observation embeddings (one augmented view)."""
        demo, obs = self.views(sample)
        return self.imitation_losses(self.model.observation_embeddings(self.model.trunk, demo, obs), sample)

    def encode_demo(self, demo: Tensor) -> Any:
        """What the policy keeps of a demonstration (B, n_demo_frames, 3, H, W) for a whole episode."""
        raise NotImplementedError

    def chunk_distribution(self, image: Tensor, state: Tensor | None, context: Any) -> DiscretizedLogisticMixture:
        """The action distribution (B, action_chunk * A) of the current frame (B, 3, H, W) given the context."""
        raise NotImplementedError

    def reset_memory(self) -> None:
        """Forget what the policy remembers of the current episode's frames (policies with a memory)."""

    # -- LeRobot interface ----------------------------------------------------------------------------------

    def get_optim_params(self) -> list[nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    def reset(self):
        """Forget the demonstration (call `set_demo` again before the next episode's first action)."""
        self._context: Any = None
        self._action_queue: deque[Tensor] = deque()  # the current chunk's targets not yet handed out
        object.__setattr__(self, "_inference_trunk", None)
        self.reset_memory()

    @property
    def has_demo(self) -> bool:
        return self._context is not None

    @torch.no_grad()
    def set_demo(self, frames: Tensor | np.ndarray) -> None:
        """Condition the policy on one demonstration for the coming episode.

        frames: the demonstrator's video, (N, 3, H, W) or (N, H, W, 3), or batched (B, N, ...), uint8 or
        float in [0, 1], at the dataset's image size. N == n_demo_frames is used as is; otherwise the first,
        last and middle-segment centre frames are picked. What the policy can compute from the demonstration
        alone is computed here once and kept until `reset()`.
        """
        frames = to_float_frames(frames)
        if frames.dim() == 4:
            frames = frames.unsqueeze(0)
        if frames.dim() != 5:
            raise ValueError(f"set_demo expects (N, 3, H, W) or (B, N, 3, H, W) frames, got shape {tuple(frames.shape)}.")
        self.check_image_size(frames, "demonstration")
        n = self.config.n_demo_frames
        if frames.shape[1] != n:
            frames = frames[:, demo_frame_indices(frames.shape[1], n)]
        # Inference uses a BatchNorm-folded channels-last copy of the trunk, rebuilt here so it follows training.
        # Kept out of the module tree (object.__setattr__): not a parameter, not in the checkpoint.
        trunk = getattr(self.acting_model, "trunk", None)
        fused = trunk.fused_for_inference() if trunk is not None and not self.training else None
        object.__setattr__(self, "_inference_trunk", fused)
        self.reset_memory()
        self._action_queue.clear()
        self._context = self.encode_demo(frames.to(self.device))

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    @property
    def acting_model(self) -> nn.Module:
        """The model the policy acts with: outside training, the weight average when the policy keeps one (and
        `act_with_weight_average`), else the trained model. In training mode always the trained one."""
        if self.training or self.averaged_model is None or not self.config.act_with_weight_average:
            return self.model
        return self.averaged_model

    def trunk_for_inference(self) -> nn.Module:
        """The fused trunk while acting (eval mode, after set_demo), else the acting model's."""
        fused = getattr(self, "_inference_trunk", None)
        return fused if fused is not None and not self.training else self.acting_model.trunk

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """Normalised targets (B, action_chunk, action_dim) for the current frame and the steps after it."""
        return self._act(batch)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """Normalised action (B, action_dim) for this control step; the postprocessor unnormalises it.

        The policy runs on every `n_action_steps`-th call (default `action_chunk`) and hands out the first
        `n_action_steps` targets of its chunk in order in between.
        """
        return self._next_action(batch)

    def _next_action(self, batch: dict[str, Tensor]) -> Tensor:
        if self.config.temporal_ensemble_coeff is not None:
            return self._ensembled_action(batch)
        if not self._action_queue:
            self.queue_chunk(self._act(batch))
        return self._action_queue.popleft()

    def queue_chunk(self, chunk: Tensor) -> None:
        """Queue the targets of a new chunk (B, action_chunk, action_dim) that are handed out before the next query:
        the first `n_action_steps` (default all), one (B, action_dim) per control step."""
        executed = chunk[:, : self.config.n_action_steps or self.config.action_chunk]
        self._action_queue.extend(executed.transpose(0, 1))

    def _ensembled_action(self, batch: dict[str, Tensor]) -> Tensor:
        """ACT's temporal ensembling: a new chunk every step; this step's target is the weighted mean of what every
        chunk still covering it says, the oldest weighted most for a positive coefficient."""
        self._action_queue.append(self._act(batch))  # (B, action_chunk, action_dim), newest last
        while len(self._action_queue) > self.config.action_chunk:
            self._action_queue.popleft()
        n = len(self._action_queue)
        targets = torch.stack([chunk[:, n - 1 - age] for age, chunk in enumerate(self._action_queue)])
        weights = torch.exp(-self.config.temporal_ensemble_coeff * torch.arange(n, dtype=targets.dtype))
        weights = weights.to(targets.device)[:, None, None]
        return (targets * weights).sum(0) / weights.sum()

    def _ensure_demo(self, batch: dict[str, Tensor]) -> None:
        if self._context is not None:
            return
        demo = next((batch[key] for key in (DEMO_FRAMES_KEY, OBS_DEMO_KEY) if key in batch), None)
        if demo is None:
            raise RuntimeError(
                f"{self.name} needs a demonstration: call policy.set_demo(video) after policy.reset(), once per "
                f"episode (or give it in the batch as '{DEMO_FRAMES_KEY}' or '{OBS_DEMO_KEY}')."
            )
        self.set_demo(demo)

    def current_inputs(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor | None]:
        """The current frame (B, 3, H, W) float and state (B, S) of an inference batch."""
        image = batch[self.camera_key]
        if image.dim() == 5:  # (B, T, 3, H, W): keep the current (last) frame
            image = image[:, -1]
        image = to_float_frames(image) if image.dtype == torch.uint8 else image.float()
        self.check_image_size(image, "observation")
        state = batch.get(OBS_STATE)
        if state is not None and state.dim() == 3:
            state = state[:, -1]
        return image, state

    def _act(self, batch: dict[str, Tensor]) -> Tensor:
        """Normalised targets (B, action_chunk, action_dim) from the current frame."""
        self._ensure_demo(batch)
        image, state = self.current_inputs(batch)
        distribution = self.chunk_distribution(image, state, self._context)
        return self.actions_of(distribution, state)

    def actions_of(self, distribution: DiscretizedLogisticMixture, state: Tensor | None) -> Tensor:
        """Normalised absolute targets (B, action_chunk, A) from the head's distribution for the current frame
        (with `hand_relative_targets`, its offsets are added to the hand position of ``state``)."""
        action = distribution.sample() if self.config.action_sampling == "sample" else distribution.mode()
        chunk = action.reshape(action.shape[0], self.config.action_chunk, self.action_dim)
        if self.hand_relative is None:
            return chunk
        if state is None:
            raise ValueError(
                f"this policy predicts targets relative to the hand: give it {OBS_STATE} (the hand position) with the image."
            )
        return self.hand_relative.to_absolute(chunk, state)

    def check_image_size(self, frames: Tensor, what: str) -> None:
        if tuple(frames.shape[-2:]) != self.image_hw or frames.shape[-3] != 3:
            raise ValueError(
                f"{what} frames are {tuple(frames.shape[-3:])} (C, H, W) but this policy was built for "
                f"(3, {self.image_hw[0]}, {self.image_hw[1]}); resize the camera or collect at that size."
            )

    # -- training -------------------------------------------------------------------------------------------

    def training_sample(self, batch: dict[str, Any]) -> TrainingSample:
        obs = batch[self.camera_key]
        if obs.dim() == 4:
            obs = obs.unsqueeze(1)
        obs = to_float_frames(obs) if obs.dtype == torch.uint8 else obs.float()
        self.check_image_size(obs, "observation")
        b, t = obs.shape[:2]
        demo = self.conditioning.demo_frames(batch).to(obs.device)
        self.check_image_size(demo, "demonstration")
        if demo.shape[1] != self.config.n_demo_frames:
            raise ValueError(f"expected {self.config.n_demo_frames} demonstration frames per sample, got {demo.shape[1]}.")
        chunks, chunk_valid = self.action_chunks(batch, t)
        obs_pad = batch.get(f"{self.camera_key}_is_pad")
        valid = ~obs_pad.reshape(b, t) if obs_pad is not None else chunk_valid[:, :, 0]
        state = batch.get(OBS_STATE)
        if state is not None and state.dim() == 2:
            state = state.unsqueeze(1)
        if self.hand_relative is not None:
            if state is None:
                raise ValueError(f"`hand_relative_targets` needs {OBS_STATE} (the hand position) in every training batch.")
            chunks = self.hand_relative.to_relative(chunks, state)  # each frame's chunk from its own hand position
        return TrainingSample(obs, demo, chunks, chunk_valid & valid[:, :, None], valid, state, batch)

    def forward(self, batch: dict[str, Any], reduction: str = "mean") -> tuple[Tensor, dict]:
        if self.training and not self._rank_streams:  # the first training step: its own augmentations per rank
            self._rank_streams = True
            rank_random_generators()
        sample = self.training_sample(batch)
        per_sample, info = self.compute_loss(sample)
        wait = self.conditioning.last_wait_s
        if wait is not None:
            info["demo_wait_s"] = wait
        b = per_sample.shape[0]
        weights = self.conditioning.sample_weights(batch, b, per_sample.device, self.training)
        if reduction == "none":
            return per_sample * weights * b, info
        loss = (per_sample * weights).sum()
        info["loss"] = loss.item()
        return loss, info

    @torch.no_grad()
    def update(self) -> None:
        """lerobot-train calls this after every optimizer step (on the unwrapped policy, every rank).

        Multi-process training: the BatchNorm running statistics are averaged over the ranks, so every rank holds
        the same state and the statistics the policy acts with come from the whole global batch (a no-op in one
        process). With `weight_average_decay` the averaged copy then takes its step towards the trained weights.
        Subclasses with their own post-step work (MOSAIC's EMA target) call this first."""
        average_batchnorm_statistics(self)
        if self.averaged_model is not None:
            decay = warmed_up_decay(int(self.weight_average_updates), self.config.weight_average_decay)
            ema_update(self.averaged_model, self.model, decay)
            self.weight_average_updates += 1

    def action_chunks(self, batch: dict[str, Any], n_frames: int) -> tuple[Tensor, Tensor]:
        """Each observation frame's chunk of targets from the sample's action window, and which are real.

        batch[ACTION]: (B, L, A) 20 Hz actions from the first observation frame on (L = (T-1) * frame_stride +
        action_chunk under lerobot-train), or (B, A) for a single frame. Positions past the window or padded
        by LeRobot (past the episode's end) are masked.
        """
        actions = batch[ACTION]
        if actions.dim() == 2:
            actions = actions.unsqueeze(1)
        b, length = actions.shape[:2]
        pad = batch.get(f"{ACTION}_is_pad")
        real = ~pad.reshape(b, length) if pad is not None else torch.ones(b, length, dtype=torch.bool, device=actions.device)
        index = torch.tensor(self.config.action_window_indices()[:n_frames], device=actions.device)  # (T, chunk)
        inside = index < length
        index = index.clamp(max=length - 1)
        return actions[:, index], real[:, index] & inside

    def views(self, sample: TrainingSample) -> tuple[Tensor, Tensor]:
        """(demo, obs) as the model sees them in training: one augmented view (none with augment off)."""
        if self.training and self.config.augment:
            return self.augment(sample.demo), self.augment(sample.obs)
        return sample.demo, sample.obs

    def bc_loss(self, distribution: DiscretizedLogisticMixture, sample: TrainingSample) -> Tensor:
        """Per-sample behaviour-cloning NLL: every observation frame predicts the chunk that follows it."""
        nll = chunk_nll(distribution, sample.chunks)  # (B, T, chunk)
        return masked_mean(nll.flatten(1), sample.chunk_valid.flatten(1)) * self.config.action_chunk

    def imitation_losses(
        self, embeddings: Tensor, sample: TrainingSample, distribution: DiscretizedLogisticMixture | None = None
    ) -> tuple[Tensor, dict[str, float]]:
        """The weighted behaviour-cloning and inverse-dynamics losses (B,) of the observation frames' embeddings
        (B, T, embed_dim), and their means to log. ``distribution``: the action head's output on them, when the
        policy builds it with more than the embeddings (default: the head on the embeddings and the state)."""
        cfg = self.config
        if distribution is None:
            distribution = self.model.action_distribution(embeddings, sample.state)
        bc = self.bc_loss(distribution, sample)
        inverse = self.inverse_loss(embeddings, sample)
        per_sample = cfg.bc_loss_weight * bc + cfg.inverse_loss_weight * inverse
        return per_sample, {"bc_loss": bc.mean().item(), "inverse_loss": inverse.mean().item()}

    def inverse_loss(self, embeddings: Tensor, sample: TrainingSample) -> Tensor:
        """Per-sample inverse-dynamics NLL: two consecutive frame embeddings -> the targets from the first on."""
        b, t = embeddings.shape[:2]
        if t < 2:
            return torch.zeros(b, device=embeddings.device)
        pair_valid = sample.chunk_valid[:, :-1] & sample.valid[:, 1:, None]
        inverse_in = torch.cat([embeddings[:, :-1], embeddings[:, 1:]], dim=-1)
        nll = chunk_nll(self.model.inverse_head(inverse_in), sample.chunks[:, :-1])
        return masked_mean(nll.flatten(1), pair_valid.flatten(1)) * self.config.action_chunk

    # -- hub ------------------------------------------------------------------------------------------------

    def generate_model_card(
        self,
        dataset_repo_id: str,
        model_type: str,
        license: str | None,
        tags: list[str] | None,
        cfg: TrainPipelineConfig | None = None,
        dataset_meta: LeRobotDatasetMetadata | None = None,
    ) -> ModelCard:
        """The Hub card ``push_model_to_hub`` writes: this toolkit's (plugin install, the demonstration input,
        mosaic-eval / lerobot-eval --env.type=mosaic), not LeRobot's real-robot ``lerobot-rollout`` card."""
        from lerobot.policies.pretrained import _build_card_context

        from .model_card import build_model_card

        context = _build_card_context(cfg, dataset_meta, self.config.input_features, self.config.output_features)
        return build_model_card(self.config, self.image_hw, dataset_repo_id, context, license, tags)
