"""Small policy checkpoints on disk (MOSAIC, ACT), written as lerobot-train writes them (config, weights, processors),
and small demonstrator datasets for the evaluation tests."""

from __future__ import annotations

from pathlib import Path

import torch

from mosaic_data.constants import policy_features

HEIGHT, WIDTH = 48, 88
"""A small camera: the environments render at the checkpoint's size."""


def write_tiny_checkpoint(folder: Path, height: int = HEIGHT, width: int = WIDTH) -> Path:
    """An untrained two-layer MOSAIC at ``height`` x ``width`` with action statistics over the workspace."""
    from pipelines.evaluation.agents import untrained_mosaic

    parts = untrained_mosaic(height, width, n_attention_layers=2, n_attention_heads=2, embed_dim=32, head_hidden_dim=32)
    for part in parts:
        part.save_pretrained(folder)
    return folder


def write_tiny_act_checkpoint(folder: Path, height: int = HEIGHT, width: int = WIDTH, chunk: int = 5) -> Path:
    """An untrained one-layer ACT (no ImageNet weights, no VAE) that predicts ``chunk`` actions at a time, with
    LeRobot's own ACT processors: a policy that takes no demonstration."""
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    config = ACTConfig(
        device="cpu",
        **policy_features(height, width),
        chunk_size=chunk,
        n_action_steps=chunk,
        dim_model=32,
        n_heads=2,
        dim_feedforward=64,
        n_encoder_layers=1,
        n_decoder_layers=1,
        use_vae=False,
        pretrained_backbone_weights=None,
        push_to_hub=False,
    )
    torch.manual_seed(0)
    policy = ACTPolicy(config)
    from pipelines.evaluation.agents import workspace_action_stats

    box = workspace_action_stats()["action"]
    stats = {
        "action": {"mean": (box["min"] + box["max"]) / 2, "std": (box["max"] - box["min"]) / 2},
        "observation.state": {"mean": torch.zeros(10), "std": torch.ones(10)},
    }
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=stats)
    for part in (policy, preprocessor, postprocessor):
        part.save_pretrained(folder)
    return folder


def write_demo_dataset(root: Path, task: str, variations: list[int], height: int = HEIGHT, width: int = WIDTH,
                       episodes: int = 2, length: int = 10) -> Path:
    """A demonstrator dataset in the collection's schema with the suite's real variation descriptions."""
    import numpy as np
    from lerobot.datasets import LeRobotDataset

    from mosaic_data.collection.schema import dataset_features
    from mosaic_data.tasks import get_task_class

    descriptions = {v.index: v.description for v in get_task_class(task).variations}
    dataset = LeRobotDataset.create(
        f"mosaic/{task}_sawyer", 20, dataset_features(height, width), root=root, use_videos=True, image_writer_threads=0
    )
    for rank in range(episodes):
        for variation in variations:
            for step in range(length):
                image = np.full((height, width, 3), 30 + 40 * rank, dtype=np.uint8)
                image[:, : 4 + step * 4, 0] = 220
                dataset.add_frame({
                    "observation.images.agentview": image,
                    "observation.state": np.zeros(10, dtype=np.float32),
                    "action": np.zeros(7, dtype=np.float32),
                    "variation": np.array([variation], dtype=np.int64),
                    "next.success": np.array([step == length - 1]),
                    "next.done": np.array([step == length - 1]),
                    "task": descriptions[variation],
                })
            dataset.save_episode()
    dataset.finalize()
    return root
