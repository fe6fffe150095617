"""Tiny LeRobot datasets in the mosaic format, written with LeRobot's own writer, and small policy configs.

Frames are flat colours that video compression keeps: red = 40 + 60 * variation, green = 40 + 80 * rank of
the episode within its variation, and a bright square that moves with time; so a test can read back which
variation and which instance a decoded frame came from.
"""

import numpy as np
import torch

from mosaic_data import constants

IMAGE_KEY = constants.CAMERA_KEY
HEIGHT, WIDTH = 32, 56
FPS = 20


def variation_description(variation: int) -> str:
    return f"open door {variation // 2} {'left' if variation % 2 == 0 else 'right'}"


def frame_image(variation: int, rank: int, step: int, height: int = HEIGHT, width: int = WIDTH) -> np.ndarray:
    image = np.zeros((height, width, 3), dtype=np.uint8)
    image[..., 0] = 40 + 60 * variation
    image[..., 1] = 40 + 80 * rank
    image[..., 2] = 60
    x = (4 + 3 * step) % (width - 8)
    image[4:12, x : x + 8, 2] = 250
    return image


def read_variation_rank(frame: torch.Tensor) -> tuple[int, int]:
    """Inverse of frame_image's colours for a (3, H, W) uint8 frame."""
    red, green = frame[0].float().median().item(), frame[1].float().median().item()
    return round((red - 40) / 60), round((green - 40) / 80)


def write_dataset(root, repo_id, variations, episodes_per_variation=2, length=12, height=HEIGHT, width=WIDTH):
    from lerobot.datasets import LeRobotDataset

    from mosaic_data.collection.schema import dataset_features

    features = dataset_features(height, width)
    dataset = LeRobotDataset.create(repo_id, FPS, features, root=root, use_videos=True, image_writer_threads=0)
    rng = np.random.default_rng(0)
    for rank in range(episodes_per_variation):
        for variation in variations:
            for step in range(length):
                last = step == length - 1
                action = np.zeros(7, dtype=np.float32)
                action[0] = 0.5 if variation % 2 == 0 else -0.5
                action[1:] = rng.uniform(-1, 1, 6)
                dataset.add_frame(
                    {
                        IMAGE_KEY: frame_image(variation, rank, step, height, width),
                        "observation.state": rng.normal(size=10).astype(np.float32),
                        "action": action,
                        "variation": np.array([variation], dtype=np.int64),
                        "next.success": np.array([last]),
                        "next.done": np.array([last]),
                        "task": variation_description(variation),
                    }
                )
            dataset.save_episode()
    dataset.finalize()
    return root


SMALL_OPTIONS: dict[str, dict] = {
    "mosaic": dict(
        n_attention_layers=2, n_attention_heads=2, contrastive_dim=16, contrastive_hidden_dim=32, attention_dropout=0.0
    ),
    "tosil": dict(n_attention_layers=2, n_attention_heads=2, attention_dropout=0.0, point_horizon=2),
    "lstm_osil": dict(lstm_hidden_dim=32, lstm_dropout=0.0),
    "mlp_osil": dict(context_hidden_dim=32, context_dim=16),
    "daml": dict(policy_hidden_dim=32, adapt_loss_channels=8),
}
"""Small sizes of each policy type's own options for fast CPU tests (one entry per type of POLICY_TYPES)."""

POLICY_TYPES = list(constants.POLICY_TYPES)


def small_flags(policy_type: str) -> list[str]:
    """``small_config``'s own options of ``policy_type`` as lerobot-train flags."""
    return [f"--policy.{name}={value}" for name, value in SMALL_OPTIONS[policy_type].items()]


def small_config(height=HEIGHT, width=WIDTH, policy_type="mosaic", **overrides):
    """A small config of ``policy_type`` for fast CPU tests (the paper's defaults are tested separately)."""
    from lerobot.configs import PreTrainedConfig

    import mosaic_policy  # noqa: F401  (registers the types)

    options = dict(
        device="cpu",
        **constants.policy_features(height, width),
        train_obs_frames=3,
        frame_stride=2,
        action_chunk=2,
        embed_dim=32,
        head_hidden_dim=32,
        push_to_hub=False,
        **SMALL_OPTIONS[policy_type],
    )
    options.update(overrides)
    return PreTrainedConfig.get_choice_class(policy_type)(**options)


def random_batch(config, batch_size=4, height=HEIGHT, width=WIDTH, seed=0):
    g = torch.Generator().manual_seed(seed)
    t, d = config.train_obs_frames, config.n_demo_frames
    n_actions = len(config.action_delta_indices)  # the 20 Hz actions of the whole window, as lerobot-train gives
    return {
        IMAGE_KEY: torch.rand(batch_size, t, 3, height, width, generator=g),
        "observation.state": torch.randn(batch_size, t, 10, generator=g),
        "action": torch.rand(batch_size, n_actions, 7, generator=g) * 2 - 1,
        "action_is_pad": torch.zeros(batch_size, n_actions, dtype=torch.bool),
        "demo_frames": torch.rand(batch_size, d, 3, height, width, generator=g),
        "task": [variation_description(i % 2) for i in range(batch_size)],
    }


def lerobot_train_help(policy_type: str) -> str:
    """What ``lerobot-train --policy.type=X --help`` prints, through LeRobot's own scoped-help parser in this
    process (a subprocess would spend most of its time importing LeRobot; the real command's plugin discovery is
    exercised by the lerobot-train runs of the suite)."""
    import contextlib
    import io

    from lerobot.configs.parser import print_scoped_help
    from lerobot.configs.train import TrainPipelineConfig

    import mosaic_policy  # noqa: F401  (registers the types, as the plugin does inside lerobot-train)

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        print_scoped_help(TrainPipelineConfig, [f"--policy.type={policy_type}", "--help"])
    return out.getvalue()
