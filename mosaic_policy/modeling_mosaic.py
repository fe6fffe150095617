"""MOSAIC: one-shot imitation conditioned on a demonstrator video, with self-attention and contrastive learning.

Per frame: ResNet-18 trunk (to layer3) -> + sinusoidal spatio-temporal encoding -> non-local attention
(demo frames self-attend; every observation frame attends to its own tokens and the demo tokens) -> per-frame
embedding -> discretised logistic mixture over actions (behaviour cloning). An inverse-dynamics head predicts
the action between consecutive observation embeddings, and a temporal contrastive loss against an EMA target
encoder shapes the representation before and/or after attention.

Training (lerobot-train): every batch holds `train_obs_frames` agent frames per sample, `frame_stride` frames
apart, and the 20 Hz actions of the whole window; every frame predicts the `action_chunk` targets that follow
it. The demonstrator frames come from `batch["demo_frames"]` if present, else from the policy's
`PairedDemoSampler` over `config.demo_repo_id` (same variation, another instance).

Inference: `policy.reset()` then `policy.set_demo(video)` once per episode (the demo tokens and every
layer's demo keys/values are cached), then `select_action(batch)` with the current frame every control step:
the policy runs once per `action_chunk` steps and hands out the predicted targets in order. An
environment can deliver the demonstration itself as the observation `observation.demo` (what
`lerobot-eval --env.type=mosaic` does): the first `select_action` after `reset()` caches it.
"""

from collections import Counter, deque
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor, nn

from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_STATE

from .attention import NonLocalAttentionStack, spatio_temporal_encoding
from .augmentation import FrameAugmentation
from .configuration_mosaic import MosaicConfig
from .contrastive import TemporalContrastiveModule, ema_momentum, ema_update, make_target, positive_indices
from .discretized_logistic import DiscretizedLogisticHead, DiscretizedLogisticMixture
from .paired_sampling import PairedDemoSampler, demo_frame_indices

if TYPE_CHECKING:
    from huggingface_hub import ModelCard
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.datasets import LeRobotDatasetMetadata

DEMO_FRAMES = "demo_frames"  # optional batch key: (B, n_demo_frames, 3, H, W) float in [0, 1]
OBS_DEMO = "observation.demo"  # the same, delivered by the environment as an observation (inference only)
EMBED_CHANNELS = 32  # channels kept per location before flattening a frame's features into its embedding


class MosaicModel(nn.Module):
    """The online network: trunk, attention, heads and contrastive modules (no EMA target here)."""

    def __init__(self, config: MosaicConfig, image_hw: tuple[int, int], state_dim: int, action_dim: int):
        super().__init__()
        from .resnet_trunk import ResNetTrunk

        self.config = config
        self.trunk = ResNetTrunk()
        channels, h, w = self.trunk.feature_shape(*image_hw)
        self.feature_shape = (channels, h, w)
        self.attention = NonLocalAttentionStack(
            channels,
            config.n_attention_layers,
            config.n_attention_heads,
            config.attention_temperature,
            config.attention_dropout,
            config.attention_pattern,
        )
        self.embed = nn.Sequential(
            nn.Conv2d(channels, EMBED_CHANNELS, 1),
            nn.ReLU(),
            nn.Flatten(),
            nn.Linear(EMBED_CHANNELS * h * w, config.embed_dim),
            nn.ReLU(),
        )
        self.state_dim = state_dim if config.use_state else 0
        # One distribution per action dimension of every target of the chunk, flattened as (chunk, action_dim).
        chunk_dim = action_dim * config.action_chunk
        self.action_head = DiscretizedLogisticHead(
            config.embed_dim + self.state_dim, chunk_dim, config.n_mixtures, config.head_hidden_dim, config.action_bins
        )
        self.inverse_head = DiscretizedLogisticHead(
            2 * config.embed_dim, chunk_dim, config.n_mixtures, config.head_hidden_dim, config.action_bins
        )

        def contrastive():
            return TemporalContrastiveModule(
                channels,
                config.contrastive_dim,
                config.contrastive_hidden_dim,
                config.contrastive_objective,
                config.contrastive_temperature,
            )

        self.contrastive_before = contrastive() if config.contrastive_before else None
        self.contrastive_after = contrastive() if config.contrastive_after else None
        d = config.n_demo_frames
        self.register_buffer("demo_position", spatio_temporal_encoding(channels, list(range(d)), h, w), persistent=False)
        # Every observation frame has the temporal code "current frame" (index n_demo_frames), whatever T is.
        self.register_buffer("obs_position", spatio_temporal_encoding(channels, [d], h, w), persistent=False)

    def trunk_features(self, trunk: nn.Module, frames: Tensor) -> Tensor:
        """(B, T, 3, H, W) -> (B, C, T, h, w)."""
        b, t = frames.shape[:2]
        features = trunk(frames.flatten(0, 1))
        return features.reshape(b, t, *features.shape[1:]).transpose(1, 2)

    def obs_position_for(self, n_frames: int) -> Tensor:
        if self.config.attention_pattern == "full":  # the baseline tells observation frames apart by time
            c, _, h, w = self.obs_position.shape
            d = self.config.n_demo_frames
            return spatio_temporal_encoding(c, list(range(d, d + n_frames)), h, w).to(self.obs_position)
        return self.obs_position

    def encode(
        self, trunk: nn.Module, attention: nn.Module, demo: Tensor, obs: Tensor, return_weights: bool = False
    ) -> dict[str, Any]:
        """Trunk + attention for demo (B, D, 3, H, W) and observation (B, T, 3, H, W) frames."""
        both = self.trunk_features(trunk, torch.cat([demo, obs], dim=1))
        d = demo.shape[1]
        demo_f, obs_f = both[:, :, :d], both[:, :, d:]
        demo_out, obs_out, weights = attention(
            demo_f + self.demo_position, obs_f + self.obs_position_for(obs.shape[1]), return_weights
        )
        return {"demo_pre": demo_f, "obs_pre": obs_f, "demo_post": demo_out, "obs_post": obs_out, "weights": weights}

    def frame_embeddings(self, obs_out: Tensor) -> Tensor:
        """(B, C, T, h, w) -> (B, T, embed_dim)."""
        b, _, t = obs_out.shape[:3]
        return self.embed(obs_out.transpose(1, 2).flatten(0, 1)).reshape(b, t, -1)

    def action_distribution(self, embeddings: Tensor, state: Tensor | None) -> DiscretizedLogisticMixture:
        if self.state_dim:
            embeddings = torch.cat([embeddings, state], dim=-1)
        return self.action_head(embeddings)


def _task_of_variation() -> dict[str, str]:
    """Variation description -> task name, from the suite's plain-data table (never the simulator: training
    must not import robosuite)."""
    from mosaic_data.tasks.spec import task_of_variation

    return task_of_variation()


def _training_steps() -> int:
    """lerobot-train's ``--steps`` from the command line (LeRobot's parser helper), else its default 100000.

    The momentum schedule of the EMA target must end with training, and a policy is not told the run's length;
    outside lerobot-train (no ``--steps`` argument) the default applies.
    """
    from lerobot.configs import parser

    steps = parser.parse_arg("steps")
    try:
        return max(1, int(steps)) if steps is not None else 100_000
    except ValueError:
        return 100_000


def _resuming() -> bool:
    """True inside ``lerobot-train --resume=true``: the checkpoint's step count continues."""
    from lerobot.configs import parser

    return (parser.parse_arg("resume") or "").lower() in ("true", "1", "yes")


def _selected_agent_episodes() -> list[int] | None:
    """lerobot-train's ``--dataset.episodes`` (e.g. ``[0,1,5]``), the agent episodes a run trains on, if given."""
    import json

    from lerobot.configs import parser

    episodes = parser.parse_arg("dataset.episodes")
    if episodes is None:
        return None
    try:
        selected = json.loads(episodes)
    except ValueError:
        raise ValueError(f"--dataset.episodes={episodes!r} is not a list of episode indices, e.g. '[0,1,2]'.") from None
    return [int(e) for e in selected] if isinstance(selected, list) else None


def _pooled(features: Tensor) -> Tensor:
    """(B, C, T, h, w) -> (B, T, C) spatial means."""
    return features.mean(dim=(3, 4)).transpose(1, 2)


def _to_float_frames(frames: Tensor | np.ndarray) -> Tensor:
    """Frames as float in [0, 1], channels first."""
    frames = torch.as_tensor(frames)
    if frames.shape[-1] == 3 and frames.shape[-3] != 3:
        frames = frames.movedim(-1, -3)
    if frames.dtype == torch.uint8:
        return frames.float() / 255.0
    return frames.float()


class MosaicPolicy(PreTrainedPolicy):
    """MOSAIC as a LeRobot policy; see the module docstring for training and inference."""

    config_class = MosaicConfig
    name = "mosaic"

    def __init__(self, config: MosaicConfig, dataset_meta=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config = config
        self.camera_key = config.camera_key
        image_shape = tuple(config.image_features[self.camera_key].shape)  # (3, H, W)
        self.image_hw = (int(image_shape[-2]), int(image_shape[-1]))
        state = config.robot_state_feature
        state_dim = int(state.shape[0]) if state is not None else 0
        if config.use_state and state is None:
            raise ValueError("`use_state` is on but the dataset has no observation.state; pass --policy.use_state=false.")
        self.action_dim = int(config.action_feature.shape[0])
        self.model = MosaicModel(config, self.image_hw, state_dim, self.action_dim)
        self.augment = FrameAugmentation(
            *self.image_hw,
            crop_scale_min=config.crop_scale_min,
            translate_fraction=config.translate_fraction,
            color_jitter=config.color_jitter,
            blur_probability=config.blur_probability,
        )
        # EMA target encoder (no gradients; updated in update() after every optimizer step).
        self.target_trunk = make_target(self.model.trunk) if config.contrastive != "off" else None
        self.target_attention = make_target(self.model.attention) if config.contrastive_after else None
        # Saved with the weights so that --resume continues the schedule; fine-tuning restarts it (from_pretrained).
        self.register_buffer("ema_step", torch.zeros((), dtype=torch.long))
        # The schedule's length is this run's, never a saved one: config.ema_total_steps if set, else --steps.
        self.ema_total_steps = config.ema_total_steps or _training_steps()
        self.demo_sampler: PairedDemoSampler | None = None
        if dataset_meta is not None and config.demo_repo_id is not None:
            self.demo_sampler = PairedDemoSampler(
                config.demo_repo_id,
                config.demo_root,
                self.camera_key,
                config.n_demo_frames,
                agent_meta=dataset_meta,
                agent_episodes=kwargs.get("agent_episodes", _selected_agent_episodes()),
                threads=config.demo_loader_threads,
                prefetch_batches=config.demo_prefetch_batches,
            )
        elif dataset_meta is not None:
            raise ValueError(
                "MOSAIC trains on agent samples paired with demonstrator videos: pass "
                "--policy.demo_repo_id=<demonstrator dataset, e.g. mosaic/door_sawyer> (and --policy.demo_root if local)."
            )
        self.reset()

    @classmethod
    def from_pretrained(cls, *args, **kwargs):
        """LeRobot's loader; a checkpoint loaded to train on a dataset (fine-tuning) restarts the EMA schedule.

        Under ``lerobot-train --resume=true`` the saved step count is kept and the schedule ends at the new
        ``--steps``; a fine-tuning run (``--policy.path=...``) would otherwise keep the finished schedule's
        momentum of 1 and freeze the target encoder for the whole run.
        """
        policy = super().from_pretrained(*args, **kwargs)
        if kwargs.get("dataset_meta") is not None and not _resuming():
            policy.ema_step.zero_()
        return policy

    def generate_model_card(
        self,
        dataset_repo_id: str,
        model_type: str,
        license: str | None,
        tags: list[str] | None,
        cfg: "TrainPipelineConfig | None" = None,
        dataset_meta: "LeRobotDatasetMetadata | None" = None,
    ) -> "ModelCard":
        """The Hub card ``push_model_to_hub`` writes: MOSAIC's (plugin install, the demonstration input,
        mosaic-eval / lerobot-eval --env.type=mosaic), not LeRobot's real-robot ``lerobot-rollout`` card."""
        from lerobot.policies.pretrained import _build_card_context

        from .model_card import build_model_card

        context = _build_card_context(cfg, dataset_meta, self.config.input_features, self.config.output_features)
        return build_model_card(self.config, self.image_hw, dataset_repo_id, context, license, tags)

    # -- LeRobot interface ----------------------------------------------------------------------------------

    def get_optim_params(self) -> list[nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    def reset(self):
        """Forget the demonstration (call `set_demo` again before the next episode's first action)."""
        self._demo_cache: list[tuple[Tensor, Tensor]] | None = None
        self._inference_trunk: nn.Module | None = None
        self._action_queue: deque[Tensor] = deque()  # the current chunk's targets not yet handed out
        self._last_weights: list[Tensor] = []

    @torch.no_grad()
    def set_demo(self, frames: Tensor | np.ndarray) -> None:
        """Condition the policy on one demonstration for the coming episode.

        frames: the demonstrator's video, (N, 3, H, W) or (N, H, W, 3), or batched (B, N, ...), uint8 or
        float in [0, 1], at the dataset's image size. N == n_demo_frames is used as is; otherwise the first,
        last and middle-segment centre frames are picked. The demo tokens and every attention layer's demo
        keys/values are computed here once and cached until `reset()`.
        """
        frames = _to_float_frames(frames)
        if frames.dim() == 4:
            frames = frames.unsqueeze(0)
        if frames.dim() != 5:
            raise ValueError(f"set_demo expects (N, 3, H, W) or (B, N, 3, H, W) frames, got shape {tuple(frames.shape)}.")
        self._check_image_size(frames, "demonstration")
        n = self.config.n_demo_frames
        if frames.shape[1] != n:
            frames = frames[:, demo_frame_indices(frames.shape[1], n)]
        if self.config.attention_pattern == "full":
            raise NotImplementedError("demo caching needs attention_pattern='mosaic'")
        device = next(self.parameters()).device
        # Inference uses a BatchNorm-folded channels-last copy of the trunk, rebuilt here so it follows training.
        # Kept out of the module tree (object.__setattr__): not a parameter, not in the checkpoint.
        object.__setattr__(self, "_inference_trunk", None if self.training else self.model.trunk.fused_for_inference())
        trunk = self._inference_trunk if self._inference_trunk is not None else self.model.trunk
        features = self.model.trunk_features(trunk, frames.to(device)) + self.model.demo_position
        _, self._demo_cache = self.model.attention.encode_demo(features)

    @property
    def has_demo(self) -> bool:
        return self._demo_cache is not None

    @torch.no_grad()
    def predict_with_attention(self, batch: dict[str, Tensor]) -> tuple[Tensor, list[Tensor]]:
        """`select_action`, and the per-layer attention weights of the frame the current chunk was predicted from.

        Weights: one tensor per layer, (B, heads, 1, h*w, h*w + n_demo_frames*h*w): each query location of that
        frame over [its own h*w tokens, then the demo tokens frame by frame], row-major over (h, w);
        `policy.model.feature_shape` gives (C, h, w).
        """
        return self._next_action(batch, return_weights=True), self._last_weights

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """Normalised targets (B, action_chunk, action_dim) for the current frame and the steps after it."""
        return self._act(batch)[0]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """Normalised action (B, action_dim) for this control step; the postprocessor unnormalises it.

        The policy runs on every `action_chunk`-th call and hands out its chunk's targets in order in between.
        """
        return self._next_action(batch)

    def _next_action(self, batch: dict[str, Tensor], return_weights: bool = False) -> Tensor:
        if not self._action_queue:
            chunk, self._last_weights = self._act(batch, return_weights)
            self._action_queue.extend(chunk.transpose(0, 1))  # (B, action_dim) per step
        return self._action_queue.popleft()

    def _act(self, batch: dict[str, Tensor], return_weights: bool = False) -> tuple[Tensor, list[Tensor]]:
        """Normalised targets (B, action_chunk, action_dim) from the current frame, and attention weights."""
        if self._demo_cache is None:
            demo = next((batch[key] for key in (DEMO_FRAMES, OBS_DEMO) if key in batch), None)
            if demo is None:
                raise RuntimeError(
                    "MOSAIC needs a demonstration: call policy.set_demo(video) after policy.reset(), once per "
                    f"episode (or give it in the batch as '{DEMO_FRAMES}' or '{OBS_DEMO}')."
                )
            self.set_demo(demo)
        image = batch[self.camera_key]
        if image.dim() == 5:  # (B, T, 3, H, W): keep the current (last) frame
            image = image[:, -1]
        image = _to_float_frames(image) if image.dtype == torch.uint8 else image.float()
        self._check_image_size(image, "observation")
        trunk = self._inference_trunk if self._inference_trunk is not None and not self.training else self.model.trunk
        obs = self.model.trunk_features(trunk, image.unsqueeze(1)) + self.model.obs_position
        cache = self._demo_cache
        if cache[0][0].shape[0] != obs.shape[0]:
            if cache[0][0].shape[0] != 1:
                raise ValueError(
                    f"the demonstration was set for {cache[0][0].shape[0]} environments but the batch has {obs.shape[0]}."
                )
            cache = [(k.expand(obs.shape[0], -1, -1, -1), v.expand(obs.shape[0], -1, -1, -1)) for k, v in cache]
        obs_out, weights = self.model.attention.attend_obs(obs, cache, return_weights)
        embeddings = self.model.frame_embeddings(obs_out)[:, 0]
        state = batch.get(OBS_STATE)
        if state is not None and state.dim() == 3:
            state = state[:, -1]
        distribution = self.model.action_distribution(embeddings, state)
        action = distribution.sample() if self.config.action_sampling == "sample" else distribution.mode()
        return action.reshape(action.shape[0], self.config.action_chunk, self.action_dim), weights

    def _check_image_size(self, frames: Tensor, what: str) -> None:
        if tuple(frames.shape[-2:]) != self.image_hw or frames.shape[-3] != 3:
            raise ValueError(
                f"{what} frames are {tuple(frames.shape[-3:])} (C, H, W) but this policy was built for "
                f"(3, {self.image_hw[0]}, {self.image_hw[1]}); resize the camera or collect at that size."
            )

    # -- training -------------------------------------------------------------------------------------------

    def _demo_frames(self, batch: dict[str, Any], n_samples: int) -> Tensor:
        if DEMO_FRAMES in batch:
            return _to_float_frames(batch[DEMO_FRAMES])
        if self.demo_sampler is None:
            raise RuntimeError(
                "no demonstrator frames: pass batch['demo_frames'] or build the policy with dataset_meta and "
                "config.demo_repo_id (lerobot-train does: --policy.demo_repo_id=...)."
            )
        tasks = batch.get("task")
        if tasks is None:
            raise RuntimeError("the batch has no 'task' strings to pair demonstrations by variation.")
        episodes = batch.get("episode_index")
        episodes = episodes.tolist() if episodes is not None else None
        return self.demo_sampler.sample(list(tasks), episodes).float() / 255.0

    def _sample_weights(self, batch: dict[str, Any], n_samples: int, device) -> Tensor:
        """Weights summing to 1: mean over the samples of a variation, then over the variations of a task,
        then over tasks (the paper's rule), whatever the batch composition.

        A variation is a LeRobot task string; its task comes from the suite's table
        (:mod:`mosaic_data.tasks.spec`; strings not found there count as one unnamed task).
        """
        if not self.config.balance_loss or "task" not in batch:
            return torch.full((n_samples,), 1.0 / n_samples, device=device)
        variations = list(batch["task"])
        task_of = _task_of_variation()
        tasks = [task_of.get(v, "") for v in variations]
        per_variation = Counter(variations)
        variations_per_task = Counter(t for t in dict(zip(variations, tasks, strict=True)).values())
        n_tasks = len(variations_per_task)
        weights = [
            1.0 / (n_tasks * variations_per_task[t] * per_variation[v]) for v, t in zip(variations, tasks, strict=True)
        ]
        return torch.tensor(weights, device=device)

    def forward(self, batch: dict[str, Any], reduction: str = "mean") -> tuple[Tensor, dict]:
        cfg = self.config
        obs = batch[self.camera_key]
        if obs.dim() == 4:
            obs = obs.unsqueeze(1)
        obs = _to_float_frames(obs) if obs.dtype == torch.uint8 else obs.float()
        self._check_image_size(obs, "observation")
        b, t = obs.shape[:2]
        device = obs.device
        demo = self._demo_frames(batch, b).to(device)
        self._check_image_size(demo, "demonstration")
        if demo.shape[1] != cfg.n_demo_frames:
            raise ValueError(f"expected {cfg.n_demo_frames} demonstration frames per sample, got {demo.shape[1]}.")
        chunks, chunk_valid = self._action_chunks(batch, t)  # (B, T, chunk, A), (B, T, chunk)
        obs_pad = batch.get(f"{self.camera_key}_is_pad")
        valid = ~obs_pad.reshape(b, t) if obs_pad is not None else chunk_valid[:, :, 0]  # real observation frames
        chunk_valid = chunk_valid & valid[:, :, None]
        state = batch.get(OBS_STATE)
        if state is not None and state.dim() == 2:
            state = state.unsqueeze(1)

        augment = self.training and cfg.augment
        view1_demo, view1_obs = (self.augment(demo), self.augment(obs)) if augment else (demo, obs)
        online = self.model.encode(self.model.trunk, self.model.attention, view1_demo, view1_obs)

        # Behaviour cloning: every observation frame predicts the chunk of targets that follows it.
        embeddings = self.model.frame_embeddings(online["obs_post"])  # (B, T, E)
        nll = self._chunk_nll(self.model.action_distribution(embeddings, state), chunks)  # (B, T, chunk)
        bc = self._masked_mean(nll.flatten(1), chunk_valid.flatten(1)) * cfg.action_chunk

        # Inverse dynamics: two consecutive embeddings -> the targets from the first frame on (its chunk).
        if t > 1:
            pair_valid = chunk_valid[:, :-1] & valid[:, 1:, None]
            inverse_in = torch.cat([embeddings[:, :-1], embeddings[:, 1:]], dim=-1)
            inverse_nll = self._chunk_nll(self.model.inverse_head(inverse_in), chunks[:, :-1])
            inverse = self._masked_mean(inverse_nll.flatten(1), pair_valid.flatten(1)) * cfg.action_chunk
        else:
            inverse = torch.zeros(b, device=device)

        per_sample = cfg.bc_loss_weight * bc + cfg.inverse_loss_weight * inverse
        info = {"bc_loss": bc.mean().item(), "inverse_loss": inverse.mean().item()}
        if cfg.contrastive != "off" and self.training:
            contrastive = self._contrastive_loss(online, demo, obs, valid)
            per_sample = per_sample + cfg.contrastive_loss_weight * contrastive
            info["contrastive_loss"] = contrastive.mean().item()
        if self.demo_sampler is not None:
            info["demo_wait_s"] = self.demo_sampler.last_wait_s

        weights = self._sample_weights(batch, b, device)
        if reduction == "none":
            return per_sample * weights * b, info
        loss = (per_sample * weights).sum()
        info["loss"] = loss.item()
        return loss, info

    def _action_chunks(self, batch: dict[str, Any], n_frames: int) -> tuple[Tensor, Tensor]:
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

    def _chunk_nll(self, distribution: DiscretizedLogisticMixture, chunks: Tensor) -> Tensor:
        """Negative log-likelihood per target (B, T, chunk), summed over action dimensions."""
        flat = chunks.flatten(-2)  # (B, T, chunk * A), the head's layout
        return -distribution.log_prob(flat).reshape(chunks.shape).sum(-1)

    @staticmethod
    def _masked_mean(values: Tensor, mask: Tensor) -> Tensor:
        mask = mask.to(values.dtype)
        return (values * mask).sum(-1) / mask.sum(-1).clamp(min=1.0)

    def _contrastive_loss(self, online: dict, demo: Tensor, obs: Tensor, valid: Tensor) -> Tensor:
        """Per-sample mean over its frames of the contrastive losses before and/or after attention."""
        cfg = self.config
        b, t = obs.shape[:2]
        d = demo.shape[1]
        view2_demo, view2_obs = (self.augment(demo), self.augment(obs)) if cfg.augment else (demo, obs)
        with torch.no_grad():
            if self.target_attention is not None:
                target = self.model.encode(self.target_trunk, self.target_attention, view2_demo, view2_obs)
            else:
                both = self.model.trunk_features(self.target_trunk, torch.cat([view2_demo, view2_obs], dim=1))
                target = {"demo_pre": both[:, :, :d], "obs_pre": both[:, :, d:]}

        # Frames of a sample: its demo frames (positive: the same frame) then its observation frames.
        obs_pos = positive_indices(b, t, cfg.contrastive_positive, cfg.positive_window, valid.cpu()).reshape(b, t)
        obs_pos = obs_pos - (torch.arange(b)[:, None] * t)  # index within the sample's observation frames
        local = torch.cat([torch.arange(d).expand(b, d), d + obs_pos], dim=1)  # (B, D + T)
        positives = (torch.arange(b)[:, None] * (d + t) + local).reshape(-1).to(obs.device)
        frame_valid = torch.cat([torch.ones(b, d, dtype=torch.bool, device=obs.device), valid], dim=1)

        total = torch.zeros(b, device=obs.device)
        for place, module in (("pre", self.model.contrastive_before), ("post", self.model.contrastive_after)):
            if module is None:
                continue
            queries = torch.cat([_pooled(online[f"demo_{place}"]), _pooled(online[f"obs_{place}"])], dim=1)
            keys = torch.cat([_pooled(target[f"demo_{place}"]), _pooled(target[f"obs_{place}"])], dim=1)
            per_frame = module.loss(
                queries.flatten(0, 1), module.keys(keys.flatten(0, 1)), positives, frame_valid.reshape(-1)
            )
            total = total + self._masked_mean(per_frame.reshape(b, d + t), frame_valid)
        return total

    @torch.no_grad()
    def update(self) -> None:
        """EMA step of the target encoder and projectors; lerobot-train calls this after every optimizer step."""
        if self.config.contrastive == "off":
            return
        momentum = ema_momentum(int(self.ema_step), self.ema_total_steps, self.config.ema_momentum)
        ema_update(self.target_trunk, self.model.trunk, momentum)
        if self.target_attention is not None:
            ema_update(self.target_attention, self.model.attention, momentum)
        for module in (self.model.contrastive_before, self.model.contrastive_after):
            if module is not None:
                module.update_target(momentum)
        self.ema_step += 1
