"""Options every demonstration-conditioned policy shares (MOSAIC and the paper's baselines).

One place for the demonstrator dataset, the time scale (frames per sample, stride, action chunk), the action
head, the augmentations, the loss balancing and the optimiser, so that every row of the paper's Table I trains on
the same samples with the same head and the same budget. A policy's own configuration subclasses this one and
adds its architecture's options.
"""

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from lerobot.configs import FeatureType, NormalizationMode, PreTrainedConfig
from lerobot.optim import AdamConfig

from mosaic_data.constants import N_DEMO_FRAMES, STATE_NAMES, VISION_BACKBONES

from .run_progress import LR_SCHEDULES, RunProgressSchedulerConfig

ACTION_SAMPLING = ("mode", "sample")
VisionBackbone = Literal[VISION_BACKBONES]  # a Literal: draccus refuses another value naming the choices
"""Trunks `vision_backbone` can name (mosaic_policy.common.trunks.make_trunk builds them)."""
LrSchedule = Literal[LR_SCHEDULES]
"""Learning-rate schedules `lr_schedule` can name (mosaic_policy.common.run_progress)."""


@dataclass
class DemoConditionedConfig(PreTrainedConfig):
    """Shared options; see each policy's configuration for its architecture.

    Time scale: datasets are recorded at 20 Hz, the paper's policy acts at about 4 Hz (its original code repeats
    every action 5 times). A policy is queried every `action_chunk` (5) control steps and predicts the next
    `action_chunk` 20 Hz targets, executed in order; a training sample holds `train_obs_frames` (7) agent frames
    `frame_stride` (5) frames apart, i.e. 1.75 s as in the paper. Every sample is paired with `n_demo_frames`
    frames of one demonstrator episode of the same variation (same LeRobot task string) and another instance:
    first, last, and one random frame from each middle segment. Actions are normalised to [-1, 1] (MIN_MAX) and
    modelled per dimension by a discretised logistic mixture over `action_bins` bins. Images only (the paper);
    `use_state` adds the robot state.

    The options changed most: `demo_repo_id` / `demo_root` (the demonstrator dataset, needed for training),
    `vision_backbone` ("conv" trains on a CPU; both trunks give 256 x H/16 x W/16 features, so the rest of every
    policy is the same), the time scale above and `use_state`. The batch size is lerobot-train's --batch_size.
    """

    # Repo id of the demonstrator dataset, same variations (LeRobot task strings) as the agent dataset.
    demo_repo_id: str | None = None
    # Local folder of the demonstrator dataset (default: $HF_LEROBOT_HOME/<demo_repo_id>).
    demo_root: str | None = None
    # Background threads decoding demonstrator frames while the model trains (0: synchronous).
    demo_loader_threads: int = 2
    # Batches of demonstrator samples per variation kept decoded ahead of the training step.
    demo_prefetch_batches: int = 2

    # Camera used by the policy; None picks the single (or first) visual input feature.
    image_key: str | None = None
    # Demonstration frames (first, last, one random frame per middle segment).
    n_demo_frames: int = N_DEMO_FRAMES
    # Observation frames per training sample, frame_stride dataset frames apart (7 x 0.25 s, the paper's window).
    train_obs_frames: int = 7
    # Dataset frames between consecutive observation frames of a sample (5 at 20 Hz = the paper's 4 Hz).
    frame_stride: int = 5
    # 20 Hz targets predicted per query, executed in order (the policy is queried every action_chunk steps).
    action_chunk: int = 5
    # Observation frames per inference step (the paper uses the current frame only).
    eval_obs_frames: int = 1

    # Normalisation per feature type: state MEAN_STD, action MIN_MAX to [-1, 1] (the head's bins), camera IDENTITY.
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.MEAN_STD,
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )

    # Vision trunk: "resnet18" (the paper's, 2.8M params) or "conv" (4 strided convs, 0.39M params, for CPU training); same 256 x H/16 x W/16 features.
    vision_backbone: VisionBackbone = "resnet18"
    # Channels of the conv trunk's features, the width of everything after it (attention, embedding): 256 as the
    # resnet18 trunk's; fewer make a cheaper step (128: 0.51 s against 0.65 s in lerobot-train on 2 cores, and
    # less learned per step). The resnet18 trunk always gives 256.
    conv_channels: int = 256
    # Spatial soft-argmax keypoints of the conv trunk's third layer (H/8 x W/8), as 2K of its `conv_channels`: finer
    # positions than its H/16 x W/16 map gives (0: none).
    conv_keypoints: int = 0
    # Per-frame embedding size fed to the action and inverse-dynamics heads.
    embed_dim: int = 256
    # Hidden width of the action / inverse-dynamics MLPs.
    head_hidden_dim: int = 256
    # Concatenate the normalised robot state to the embedding in the action head (the paper: images only).
    use_state: bool = False
    # With use_state: the state components the head reads, by name, e.g. [gripper_opening] (empty: all of them).
    state_components: list[str] = field(default_factory=list)
    # Predict each chunk's x, y, z targets as offsets from the hand position of the frame that predicts it
    # (observation.state x, y, z), converted back to absolute targets inside the policy: one frame then needs the
    # next move's direction, not the hand's exact place in the image. Rotation and gripper stay absolute.
    hand_relative_targets: bool = False
    # Logistic mixture components per action dimension. With several, the head can give each variation's target a
    # component weighted alike whatever the demonstration and act with the heaviest (the same variation every time);
    # with 1 only the demonstration can move the target.
    n_mixtures: int = 3
    # Discretisation bins per action dimension over the normalised range [-1, 1].
    action_bins: int = 256
    # Inference: "mode" (mean of the most likely component) or "sample".
    action_sampling: str = "mode"
    # Inference: query the policy every control step and average the targets its chunks give for that step, weight
    # exp(-coeff * i) for the i-th oldest (ACT's temporal ensembling); unset: hand out each chunk's targets in turn.
    temporal_ensemble_coeff: float | None = None
    # Inference: hand out only the first n targets of each chunk, then query the policy again (LeRobot's ACT and
    # Diffusion name it so); unset: the whole chunk. Fewer steps per query react sooner to where the hand is.
    n_action_steps: int | None = None
    # Keep an exponential moving average of the weights with this decay (e.g. 0.998: about the last 500 steps;
    # warmed up over the first steps) and act with it; unset: act with the trained weights. The average is saved in
    # the checkpoint beside them (twice the file), so resuming goes on training the trained weights.
    weight_average_decay: float | None = None
    # With weight_average_decay: act with the average (true) or with the trained weights of the same checkpoint.
    act_with_weight_average: bool = True

    # Weight of the behaviour-cloning loss (paper: 1).
    bc_loss_weight: float = 1.0
    # Weight of the inverse-dynamics loss (paper: 1).
    inverse_loss_weight: float = 1.0

    # Training augmentations (translate/crop, colour jitter, Gaussian blur); never at inference.
    augment: bool = True
    # Smallest area fraction kept by the random resized crop.
    crop_scale_min: float = 0.8
    # Largest random translation as a fraction of the image size.
    translate_fraction: float = 0.05
    # Brightness / contrast / saturation jitter strength (hue: a quarter of it).
    color_jitter: float = 0.2
    # Probability of a Gaussian blur.
    blur_probability: float = 0.3

    # Average the loss per variation, then per task, whatever the batch composition.
    balance_loss: bool = True

    # Adam learning rate (paper: 5e-4).
    optimizer_lr: float = 5e-4
    # Adam weight decay.
    optimizer_weight_decay: float = 0.0
    # Learning rate over the run: "constant" (the paper) or "cosine" (down to lr_final_ratio of it at the last step).
    lr_schedule: LrSchedule = "constant"
    # With lr_schedule=cosine: the learning rate at the run's last step, as a fraction of optimizer_lr.
    lr_final_ratio: float = 0.1

    def __post_init__(self):
        super().__post_init__()
        if self.action_sampling not in ACTION_SAMPLING:
            raise ValueError(
                f"`action_sampling` must be one of {ACTION_SAMPLING}, got {self.action_sampling!r}: "
                "pass e.g. --policy.action_sampling=mode."
            )
        unknown = [name for name in self.state_components if name not in STATE_NAMES]
        if unknown:
            raise ValueError(f"`state_components` {unknown} unknown: choose among {', '.join(STATE_NAMES)}.")
        if self.vision_backbone not in VISION_BACKBONES:
            raise ValueError(
                f"`vision_backbone` must be one of {VISION_BACKBONES}, got {self.vision_backbone!r}: "
                "pass e.g. --policy.vision_backbone=conv."
            )
        if self.conv_channels < 8 or self.conv_channels % 8:
            raise ValueError(f"`conv_channels` must be a multiple of 8 (e.g. 128 or 256), got {self.conv_channels}.")
        if self.conv_keypoints < 0 or 2 * self.conv_keypoints >= self.conv_channels:
            raise ValueError(
                f"`conv_keypoints` must be >= 0 and fill fewer than the {self.conv_channels} `conv_channels` (2 per "
                f"keypoint), got {self.conv_keypoints}: e.g. --policy.conv_keypoints=16."
            )
        if self.vision_backbone != "conv" and self.conv_keypoints:
            raise ValueError(
                f"`conv_keypoints` adds keypoints to the conv trunk; the {self.vision_backbone} trunk has none: pass "
                "--policy.vision_backbone=conv with it."
            )
        if self.vision_backbone != "conv" and self.conv_channels != 256:
            raise ValueError(
                f"`conv_channels`={self.conv_channels} sets the conv trunk's width; the {self.vision_backbone} trunk "
                "gives 256: pass --policy.vision_backbone=conv with it."
            )
        if self.n_demo_frames < 2:
            raise ValueError(f"`n_demo_frames` must be >= 2 (first and last frame), got {self.n_demo_frames}.")
        for name in ("train_obs_frames", "eval_obs_frames", "frame_stride", "action_chunk", "n_mixtures", "embed_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}.")
        if self.n_action_steps is not None and not 1 <= self.n_action_steps <= self.action_chunk:
            raise ValueError(
                f"`n_action_steps` must be between 1 and `action_chunk` ({self.action_chunk}), got "
                f"{self.n_action_steps}: e.g. --policy.n_action_steps={max(1, self.action_chunk // 2)}."
            )
        if self.n_action_steps is not None and self.temporal_ensemble_coeff is not None:
            raise ValueError(
                "`n_action_steps` and `temporal_ensemble_coeff` both set how often the policy is queried (temporal "
                "ensembling queries it every step): pass one of them."
            )
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(
                f"`lr_schedule` must be one of {LR_SCHEDULES}, got {self.lr_schedule!r}: "
                "pass e.g. --policy.lr_schedule=cosine."
            )
        if self.weight_average_decay is not None and not 0.0 < self.weight_average_decay < 1.0:
            raise ValueError(
                f"`weight_average_decay` must be in (0, 1), got {self.weight_average_decay}: pass e.g. "
                "--policy.weight_average_decay=0.998, or leave it unset to act with the trained weights."
            )
        if not 0.0 <= self.lr_final_ratio <= 1.0:
            raise ValueError(f"`lr_final_ratio` must be in [0, 1], got {self.lr_final_ratio}.")
        if self.action_bins < 2:
            raise ValueError(f"`action_bins` must be >= 2, got {self.action_bins}.")
        if self.demo_loader_threads < 0:
            raise ValueError(f"`demo_loader_threads` must be >= 0, got {self.demo_loader_threads}.")

    def _save_pretrained(self, save_directory: Path) -> None:
        """config.json without ``demo_root``: a folder of this machine, meaningless where the policy is loaded
        (the Hub, another machine). A loaded policy that trains again finds its demonstrator dataset in
        LeRobot's cache ($HF_LEROBOT_HOME/<demo_repo_id>) unless ``--policy.demo_root`` is given again;
        evaluation never reads it. (lerobot-train's own train_config.json keeps the run's paths for --resume.)
        """
        demo_root, self.demo_root = self.demo_root, None
        try:
            super()._save_pretrained(save_directory)
        finally:
            self.demo_root = demo_root

    def get_optimizer_preset(self) -> AdamConfig:
        return AdamConfig(lr=self.optimizer_lr, weight_decay=self.optimizer_weight_decay)

    def get_scheduler_preset(self) -> RunProgressSchedulerConfig:
        """The learning-rate schedule (``lr_schedule``) through a scheduler that knows the run's length (lerobot-train
        tells a scheduler `--steps`): schedules inside the policy (MOSAIC's EMA momentum) end with the run."""
        return RunProgressSchedulerConfig(schedule=self.lr_schedule, final_lr_ratio=self.lr_final_ratio)

    @property
    def camera_key(self) -> str:
        """The visual feature the policy reads."""
        if self.image_key is not None:
            return self.image_key
        if not self.image_features:
            raise ValueError(f"{self.type} needs one camera among the input features (e.g. observation.images.agentview).")
        return next(iter(self.image_features))

    def validate_features(self) -> None:
        if not self.image_features:
            raise ValueError(f"{self.type} needs a camera input (e.g. observation.images.agentview); the dataset has none.")
        if self.image_key is not None and self.image_key not in self.image_features:
            raise ValueError(
                f"`image_key`={self.image_key!r} is not a visual input feature; available: {sorted(self.image_features)}."
            )
        if self.action_feature is None:
            raise ValueError(f"{self.type} needs an `action` output feature.")
        if self.image_features[self.camera_key].type is not FeatureType.VISUAL:
            raise ValueError(f"{self.camera_key} is not a visual feature.")

    @property
    def drop_n_last_frames(self) -> int:
        """Every frame may start a sample: frames past an episode's end are padded and masked (`*_is_pad`)."""
        return 0

    @property
    def observation_delta_indices(self) -> list[int]:
        return [i * self.frame_stride for i in range(self.train_obs_frames)]

    @property
    def action_delta_indices(self) -> list[int]:
        """Every 20 Hz action from the first observation frame to the end of the last frame's chunk."""
        return list(range((self.train_obs_frames - 1) * self.frame_stride + self.action_chunk))

    def action_window_indices(self) -> list[list[int]]:
        """For each observation frame of a sample, the positions of its chunk in the sample's action window."""
        return [[i * self.frame_stride + j for j in range(self.action_chunk)] for i in range(self.train_obs_frames)]

    @property
    def reward_delta_indices(self) -> None:
        return None
