"""MOSAIC: one-shot imitation conditioned on a demonstrator video, with self-attention and contrastive learning.

Per frame: ResNet-18 trunk (to layer3; `vision_backbone`) -> + sinusoidal spatio-temporal encoding -> non-local
attention (demo frames self-attend; every observation frame attends to its own tokens and the demo tokens) ->
per-frame embedding (with `demo_summary`, joined with an ordered summary vector of the attended demo frames) ->
discretised logistic mixture over actions (behaviour cloning). An inverse-dynamics head
predicts the action between consecutive observation embeddings, and a temporal contrastive loss against an EMA
target encoder shapes the representation before and/or after attention; with `variation_loss_weight`, a
supervised contrastive loss groups the batch's attended demonstrations by variation, and with
`wrong_demo_loss_weight` the recorded actions must be likelier with the sample's own demonstration than with
another variation's (:mod:`.wrong_demonstration`).

The trunk, embedding and heads are those of :class:`~mosaic_policy.common.demo_conditioned_model.DemoConditionedModel`
(the same in every row of the table); this module builds the attention and the contrastive modules.
Training and inference follow :mod:`mosaic_policy.common.demo_conditioned_policy` (the interface every
demo-conditioned policy shares). Acting, every layer's demo keys/values (and the summary) are computed once
per episode by `set_demo` and cached; `predict_with_attention` also returns the attention weights.
"""

from typing import Any

import torch
from torch import Tensor, nn

from ..common.attention import NonLocalAttentionStack, spatio_temporal_encoding
from ..common.demo_conditioned_model import DemoConditionedModel
from ..common.demo_conditioned_policy import (
    DemoConditionedPolicy,
    TrainingSample,
    chunk_nll,
    expand_to_batch,
    masked_mean,
)
from ..common.demo_summary import context_mlp, fuse_with_context, fusion_layer
from ..common.discretized_logistic import DiscretizedLogisticMixture
from ..common.frame_features import FrameMemory, trunk_features
from ..common.run_progress import run_progress
from ..common.weight_average import ema_update, frozen_copy
from .configuration_mosaic import MosaicConfig
from .contrastive import TemporalContrastiveModule, ema_momentum, positive_indices
from .variation_contrastive import nearest_is_same_variation, variation_contrastive_loss, variation_projector
from .wrong_demonstration import (
    nearest_other_variation_partners,
    other_variation_partners,
    wrong_demonstration_loss,
)

DEFAULT_EMA_STEPS = 100_000
"""EMA schedule length outside a lerobot-train run that tells it (LeRobot's default --steps)."""


class MosaicModel(DemoConditionedModel):
    """The online network: the shared trunk, embedding and heads, attention (and with `demo_summary` the ordered
    demo summary) as the task context, and the contrastive modules (no EMA target here)."""

    def __init__(self, config: MosaicConfig, image_hw: tuple[int, int], state_dim: int, action_dim: int):
        super().__init__(config, image_hw, state_dim, action_dim)
        channels, h, w = self.feature_shape

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
        self.variation_projector = None
        if config.variation_loss_weight > 0:
            demo_dim = config.n_demo_frames * config.embed_dim
            self.variation_projector = variation_projector(demo_dim, config.contrastive_hidden_dim, config.contrastive_dim)
        d = config.n_demo_frames
        self.mixture_gate = None
        if config.mixture_weights == "demo":
            self.mixture_gate = nn.Linear(config.summary_dim, action_dim * config.action_chunk * config.n_mixtures)
        self.register_buffer("demo_position", spatio_temporal_encoding(channels, list(range(d)), h, w), persistent=False)
        # Every observation frame has the temporal code "current frame" (index n_demo_frames), whatever T is.
        self.register_buffer("obs_position", spatio_temporal_encoding(channels, [d], h, w), persistent=False)

    def build_context(self, channels: int, height: int, width: int) -> None:
        config = self.config
        self.attention = NonLocalAttentionStack.from_config(config, channels, config.attention_pattern)
        self.summary, self.summary_fuse = None, None
        if config.demo_summary:
            demo_dim = config.n_demo_frames * config.embed_dim
            self.summary = context_mlp(demo_dim, 2, config.summary_hidden_dim, config.summary_dim)
            self.summary_fuse = fusion_layer(config.embed_dim, config.summary_dim)

    def attend_demo(self, trunk: nn.Module, demo: Tensor) -> tuple[Tensor, list[tuple[Tensor, Tensor]]]:
        """(B, D, 3, H, W) demo frames -> attended demo features (B, C, D, h, w) and every attention layer's demo
        keys/values: the demo stream, which depends on the demo only."""
        return self.attention.encode_demo(trunk_features(trunk, demo) + self.demo_position)

    def summarize_demo(self, demo_post: Tensor) -> Tensor | None:
        """(B, C, D, h, w) attended demo features -> (B, summary_dim) ordered summary; None without `demo_summary`."""
        if self.summary is None:
            return None
        return self.summary(self.frame_embeddings(demo_post).flatten(1))

    def conditioned_embeddings(self, obs_post: Tensor, summary: Tensor | None) -> Tensor:
        """(B, C, T, h, w) attended observation features and the demo summary (or None) -> (B, T, embed_dim)."""
        embeddings = self.frame_embeddings(obs_post)
        return embeddings if summary is None else fuse_with_context(self.summary_fuse, embeddings, summary)

    def mixture_logits(self, summary: Tensor | None) -> Tensor | None:
        """(B, action_chunk * A, n_mixtures) mixture weights (logits) from the demonstration summary with
        `mixture_weights="demo"`; None when the frame's embedding sets them (the paper)."""
        if self.mixture_gate is None:
            return None
        return self.mixture_gate(summary).reshape(summary.shape[0], -1, self.config.n_mixtures)

    def head_distribution(
        self, embeddings: Tensor, state: Tensor | None, summary: Tensor | None
    ) -> DiscretizedLogisticMixture:
        """The action distribution of observation embeddings (B, ..., embed_dim) given the demonstration summary."""
        return self.action_distribution(embeddings, state, self.mixture_logits(summary))

    def embeddings_of(self, encoded: dict[str, Any]) -> Tensor:
        """What the heads read, from the output of :meth:`encode`."""
        return self.conditioned_embeddings(encoded["obs_post"], self.summarize_demo(encoded["demo_post"]))

    def obs_position_for(self, n_frames: int) -> Tensor:
        if self.config.attention_pattern == "full":  # frames that see each other are told apart by time
            c, _, h, w = self.obs_position.shape
            d = self.config.n_demo_frames
            return spatio_temporal_encoding(c, list(range(d, d + n_frames)), h, w).to(self.obs_position)
        return self.obs_position

    def encode(
        self, trunk: nn.Module, attention: nn.Module, demo: Tensor, obs: Tensor, return_weights: bool = False
    ) -> dict[str, Any]:
        """Trunk + attention for demo (B, D, 3, H, W) and observation (B, T, 3, H, W) frames."""
        both = trunk_features(trunk, torch.cat([demo, obs], dim=1))
        d = demo.shape[1]
        demo_f, obs_f = both[:, :, :d], both[:, :, d:]
        demo_out, cache = attention.encode_demo(demo_f + self.demo_position)
        obs_in = obs_f + self.obs_position_for(obs.shape[1])
        obs_out, weights = attention.attend_observations(obs_in, cache, return_weights)
        return {
            "demo_pre": demo_f, "obs_pre": obs_f, "demo_post": demo_out, "obs_post": obs_out, "weights": weights,
            "obs_in": obs_in, "cache": cache,
        }

    def observation_embeddings(self, trunk: nn.Module, demo: Tensor, obs: Tensor) -> Tensor:
        return self.embeddings_of(self.encode(trunk, self.attention, demo, obs))


def _pooled(features: Tensor) -> Tensor:
    """(B, C, T, h, w) -> (B, T, C) spatial means."""
    return features.mean(dim=(3, 4)).transpose(1, 2)


class MosaicPolicy(DemoConditionedPolicy):
    """MOSAIC as a LeRobot policy; see the module docstring."""

    config_class = MosaicConfig
    name = "mosaic"

    def build(self, image_hw: tuple[int, int], state_dim: int, action_dim: int) -> None:
        config = self.config
        self.model = MosaicModel(config, image_hw, state_dim, action_dim)
        # EMA target encoder (no gradients; updated in update() after every optimizer step).
        self.target_trunk = frozen_copy(self.model.trunk) if config.contrastive != "off" else None
        self.target_attention = frozen_copy(self.model.attention) if config.contrastive_after else None
        # Optimiser steps seen by update(); the EMA schedule's clock outside a lerobot-train run that tells it
        # (lerobot-train's scheduler restarts on fine-tuning and is restored on --resume: see run_progress).
        self.register_buffer("ema_step", torch.zeros((), dtype=torch.long))
        self._memory = FrameMemory(config.train_obs_frames)
        self._last_weights: list[Tensor] = []

    def reset_memory(self) -> None:
        self._memory = FrameMemory(self.config.train_obs_frames)
        self._last_weights = []

    # -- inference ------------------------------------------------------------------------------------------

    def encode_demo(self, demo: Tensor) -> dict[str, Any]:
        """Every attention layer's demo keys/values ("cache") and, with `demo_summary`, the summary vector
        ("summary"): the demo stream depends on the demo only."""
        model = self.acting_model
        demo_out, cache = model.attend_demo(self.trunk_for_inference(), demo)
        summary = model.summarize_demo(demo_out)
        return {"cache": cache} if summary is None else {"cache": cache, "summary": summary}

    @torch.no_grad()
    def predict_with_attention(self, batch: dict[str, Tensor]) -> tuple[Tensor, list[Tensor]]:
        """`select_action`, and the per-layer attention weights of the frame the current chunk was predicted from.

        Weights: one tensor per layer, (B, heads, 1, h*w, h*w + n_demo_frames*h*w): each query location of that
        frame over [its own h*w tokens, then the demo tokens frame by frame], row-major over (h, w);
        `policy.model.feature_shape` gives (C, h, w). The full pattern returns no weights.
        """
        if not self._action_queue:
            self.queue_chunk(self._act(batch, return_weights=True))
        return self._action_queue.popleft(), self._last_weights

    def _act(self, batch: dict[str, Tensor], return_weights: bool = False) -> Tensor:
        self._ensure_demo(batch)
        image, state = self.current_inputs(batch)
        distribution = self._distribution(image, state, self._context, return_weights)
        return self.actions_of(distribution, state)

    def chunk_distribution(self, image: Tensor, state: Tensor | None, context: Any) -> DiscretizedLogisticMixture:
        return self._distribution(image, state, context, return_weights=False)

    def _distribution(
        self, image: Tensor, state: Tensor | None, context: dict[str, Any], return_weights: bool
    ) -> DiscretizedLogisticMixture:
        model = self.acting_model
        features = trunk_features(self.trunk_for_inference(), image.unsqueeze(1))
        context = expand_to_batch(context, features.shape[0])
        cache = context["cache"]
        if self.config.attention_pattern == "full":  # recompute over the remembered frames, keep the current one
            window = self._memory.push(features[:, :, 0])
            obs = window + model.obs_position_for(window.shape[2])
            obs_out, self._last_weights = model.attention.attend_obs_causal(obs, cache)[:, :, -1:], []
        else:
            obs = features + model.obs_position
            obs_out, self._last_weights = model.attention.attend_obs(obs, cache, return_weights)
        summary = context.get("summary")
        embeddings = model.conditioned_embeddings(obs_out, summary)[:, 0]
        return model.head_distribution(embeddings, state, summary)

    # -- training -------------------------------------------------------------------------------------------

    def compute_loss(self, sample: TrainingSample) -> tuple[Tensor, dict[str, float]]:
        cfg = self.config
        view1_demo, view1_obs = self.views(sample)
        online = self.model.encode(self.model.trunk, self.model.attention, view1_demo, view1_obs)
        summary = self.model.summarize_demo(online["demo_post"])
        embeddings = self.model.conditioned_embeddings(online["obs_post"], summary)
        distribution = self.model.head_distribution(embeddings, sample.state, summary)
        per_sample, info = self.imitation_losses(embeddings, sample, distribution)
        if cfg.contrastive != "off" and self.training:
            contrastive = self._contrastive_loss(online, sample.demo, sample.obs, sample.valid)
            per_sample = per_sample + cfg.contrastive_loss_weight * contrastive
            info["contrastive_loss"] = contrastive.mean().item()
        tasks = sample.batch.get("task")
        tasks = list(tasks) if tasks is not None else None
        wanted = cfg.wrong_demo_loss_weight > 0 and self.training and tasks is not None
        partners = self._wrong_demonstration_partners(online, tasks) if wanted else None
        if partners is not None:
            wrong = self._wrong_demonstration_loss(online, summary, distribution, partners, sample)
            per_sample = per_sample + cfg.wrong_demo_loss_weight * wrong
            info["wrong_demo_loss"] = wrong.mean().item()
        if self.model.variation_projector is not None and self.training and tasks is not None:
            projections = self.model.variation_projector(self._demo_vectors(online))
            variation = variation_contrastive_loss(projections, tasks, cfg.contrastive_temperature)
            per_sample = per_sample + cfg.variation_loss_weight * variation
            info["variation_loss"] = variation.mean().item()
            nearest = nearest_is_same_variation(projections, tasks)
            if nearest is not None:  # a batch where no two samples share a variation has nothing to tell
                info["variation_nearest"] = nearest
        return per_sample, info

    def _wrong_demonstration_partners(self, online: dict, tasks: list[str]) -> Tensor | None:
        """Every sample's wrong demonstration for the wrong-demonstration loss (`wrong_demo_partner`)."""
        if self.config.wrong_demo_partner == "nearest":
            return nearest_other_variation_partners(self._demo_vectors(online), tasks)
        partners = other_variation_partners(tasks)
        return None if partners is None else partners.to(online["demo_post"].device)

    def _demo_vectors(self, online: dict) -> Tensor:
        """(B, D * embed_dim) the attended demonstration's frame embeddings in order, computed once per step for
        the variation projector and the nearest wrong-demonstration partner."""
        if "demo_vectors" not in online:
            online["demo_vectors"] = self.model.frame_embeddings(online["demo_post"]).flatten(1)
        return online["demo_vectors"]

    def _wrong_demonstration_loss(
        self,
        online: dict,
        summary: Tensor | None,
        right: DiscretizedLogisticMixture,
        partners: Tensor,
        sample: TrainingSample,
    ) -> Tensor:
        """Per-sample :func:`wrong_demonstration_loss`: the observation frames attend to (and are joined with the
        summary of) the demonstration of sample ``partners[i]``, another variation's, and the recorded chunks'
        likelihoods with the right demonstration (``right``, the behaviour-cloning loss's distribution) and the
        wrong one are compared frame by frame."""
        cache = [(keys[partners], values[partners]) for keys, values in online["cache"]]
        obs_wrong, _ = self.model.attention.attend_observations(online["obs_in"], cache)
        wrong_summary = None if summary is None else summary[partners]
        wrong = self.model.head_distribution(
            self.model.conditioned_embeddings(obs_wrong, wrong_summary), sample.state, wrong_summary
        )
        nll = [(chunk_nll(d, sample.chunks) * sample.chunk_valid).sum(-1) for d in (right, wrong)]
        return wrong_demonstration_loss(*nll, sample.chunk_valid.any(-1))

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
                both = trunk_features(self.target_trunk, torch.cat([view2_demo, view2_obs], dim=1))
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
            total = total + masked_mean(per_frame.reshape(b, d + t), frame_valid)
        return total

    def ema_schedule(self) -> tuple[int, int]:
        """(step, total steps) of the EMA momentum schedule: the lerobot-train run's progress when a run told its
        length to the scheduler preset, else the policy's own step count over `ema_total_steps` (or 100000)."""
        progress = run_progress()
        if progress is not None:
            steps_taken, total = progress
            step = max(steps_taken - 1, 0)  # lerobot-train steps the scheduler before calling update()
        else:
            step, total = int(self.ema_step), DEFAULT_EMA_STEPS
        return step, self.config.ema_total_steps or total

    @torch.no_grad()
    def update(self) -> None:
        """EMA step of the target encoder and projectors; lerobot-train calls this after every optimizer step.

        Every rank of a multi-process run does the same step: the online weights are the same after the optimizer
        step (DDP averaged the gradients), the BatchNorm statistics the target copies are first averaged over the
        ranks (``super().update()``) and the momentum follows the run's step count, the same on every rank."""
        super().update()
        if self.config.contrastive == "off":
            return
        momentum = ema_momentum(*self.ema_schedule(), self.config.ema_momentum)
        ema_update(self.target_trunk, self.model.trunk, momentum)
        if self.target_attention is not None:
            ema_update(self.target_attention, self.model.attention, momentum)
        for module in (self.model.contrastive_before, self.model.contrastive_after):
            if module is not None:
                module.update_target(momentum)
        self.ema_step += 1
