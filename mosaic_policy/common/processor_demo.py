"""Pre/post-processing pipelines of every demo-conditioned policy: LeRobot's defaults with the dataset's stats.

Pre: batch dim, device, normalisation (state MEAN_STD, action MIN_MAX to [-1, 1] for the discretised
logistic head, camera IDENTITY: the trunk sees [0, 1] pixels). Post: unnormalise the action, back to CPU.
Demonstrator frames bypass the normaliser (they are camera frames, IDENTITY anyway).
"""

from typing import Any

import torch

from lerobot.configs import PreTrainedConfig
from lerobot.processor import PolicyAction, PolicyProcessorPipeline, make_default_pre_post_processors


def make_demo_conditioned_pre_post_processors(
    config: PreTrainedConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    return make_default_pre_post_processors(config, dataset_stats, normalizer_device=config.device)
