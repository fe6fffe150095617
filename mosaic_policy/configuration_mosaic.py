"""Configuration of the MOSAIC policy (multi-task one-shot imitation with self-attention and contrastive learning)."""

from dataclasses import dataclass, field
from pathlib import Path

from lerobot.configs import FeatureType, NormalizationMode, PreTrainedConfig
from lerobot.optim import AdamConfig

CONTRASTIVE_PLACEMENTS = ("off", "before", "after", "both")
POSITIVE_MODES = ("window", "fixed", "same")
CONTRASTIVE_OBJECTIVES = ("infonce", "byol")
ATTENTION_PATTERNS = ("mosaic", "full")
ACTION_SAMPLING = ("mode", "sample")


@PreTrainedConfig.register_subclass("mosaic")
@dataclass
class MosaicConfig(PreTrainedConfig):
    """Configuration of the MOSAIC policy.

    The defaults are the paper's single-task settings. Options a user most likely changes:
    `demo_repo_id` (the demonstrator dataset paired with `--dataset.repo_id`), `n_attention_layers`
    (2 single-task, 3 multi-task) and `contrastive` (ablations).

    Time scale: datasets are recorded at 20 Hz, the paper's policy acts at about 4 Hz (its original code
    repeats every action 5 times). Here the policy is queried every `action_chunk` (5) control steps and
    predicts the next `action_chunk` 20 Hz targets, executed in order (smooth motion, not a held target); a
    training sample holds `train_obs_frames` (7) agent frames `frame_stride` (5) frames apart, i.e. 1.75 s as in
    the paper, and the contrastive positive lies within +-`positive_window` of those frames (0.5 s). Every
    sample is paired with `n_demo_frames` frames of one demonstrator episode of the same variation (same
    LeRobot task string) and another instance: first, last, and one random frame from each middle segment.
    Actions are normalised to [-1, 1] (MIN_MAX) and modelled per dimension by a discretised logistic mixture
    over `action_bins` bins. The policy sees images only (the paper); `use_state` adds the robot state.

    Args:
        - demo_repo_id: Repo id of the demonstrator dataset (e.g. "mosaic/door_sawyer"); needed for training.
        - demo_root: Local folder of the demonstrator dataset (default: LeRobot's cache, $HF_LEROBOT_HOME/repo_id).
        - demo_loader_threads: Background threads decoding demonstrator frames ahead of the training step
            (0 decodes synchronously inside forward()).
        - demo_prefetch_batches: How many batches of demonstrator samples per variation are kept decoded ahead.
        - image_key: Camera feature used by the policy (default: the only/first visual input feature).
        - n_demo_frames: Demonstration frames the policy conditions on (first, last, one per middle segment).
        - train_obs_frames: Observation frames per training sample, `frame_stride` dataset frames apart.
        - frame_stride: Dataset frames between two observation frames of a training sample (5 at 20 Hz: 0.25 s,
            the paper's policy rate).
        - action_chunk: Consecutive 20 Hz targets predicted per observation; at inference the policy is queried
            once per chunk and its targets are executed in order (5: the paper's 4 Hz policy rate).
        - eval_obs_frames: Observation frames per step at inference (the paper: 1, the current frame).
        - n_attention_layers: Non-local attention layers (paper: 2 single-task, 3 multi-task).
        - n_attention_heads: Heads per attention layer.
        - attention_temperature: Softmax temperature dividing query-key dot products (paper: 16).
        - attention_pattern: "mosaic" (demo self-attends; each observation frame attends to its own tokens and
            the demo tokens) or "full" (all frames attend to all, T-OSIL style; a baseline for comparison).
        - attention_dropout: Dropout on attention outputs.
        - embed_dim: Size of the per-frame embedding fed to the heads.
        - head_hidden_dim: Hidden width of the action / inverse-dynamics MLPs.
        - use_state: Concatenate the (normalised) robot state to the frame embedding in the action head (off in
            the paper: the current grip position predicts most of the next target, a shortcut around the images
            and the demonstration).
        - n_mixtures: Logistic mixture components per action dimension.
        - action_bins: Discretisation bins per action dimension over [-1, 1].
        - action_sampling: "mode" (mean of the most likely component, deterministic) or "sample" at inference.
        - bc_loss_weight, inverse_loss_weight, contrastive_loss_weight: Loss weights (paper: 1, 1, 1).
        - contrastive: Where the temporal contrastive loss applies: "off", "before" / "after" attention, "both".
        - contrastive_objective: "infonce" (bilinear similarity, all other frames of the batch are negatives)
            or "byol" (no negatives: cosine between predictor output and target projection).
        - contrastive_positive: "window" (random frame within +-positive_window steps), "fixed" (the frame
            exactly positive_window steps away) or "same" (the same frame; the two views differ only by
            augmentation).
        - positive_window: k of the positive modes above, in observation frames (`frame_stride` dataset frames each).
        - contrastive_dim, contrastive_hidden_dim: Projector / predictor output and hidden widths.
        - contrastive_temperature: InfoNCE temperature applied to the bilinear logits of normalised vectors.
        - ema_momentum: Initial momentum of the EMA target encoder (rises to 1 with a cosine schedule).
        - ema_total_steps: Steps over which the momentum reaches 1; by default lerobot-train's `--steps` of the
            current run (read from its command line when the policy is built for training, as LeRobot's own parser
            does for paths). Fine-tuning a checkpoint (`--policy.path`) starts a new schedule; `--resume` keeps the
            step count and stretches the schedule to the new `--steps`.
        - augment: Apply the training augmentations (never used at inference).
        - crop_scale_min: Smallest area fraction kept by the random resized crop.
        - translate_fraction: Largest random translation, as a fraction of width / height.
        - color_jitter: Strength of brightness / contrast / saturation jitter (hue gets a quarter of it).
        - blur_probability: Probability of a Gaussian blur (kernel 5, sigma 0.1-2).
        - balance_loss: Average the loss per variation, then per task (the paper's rule), whatever the batch mix.
        - optimizer_lr: Adam learning rate (paper: 5e-4). Batch size is lerobot-train's `--batch_size` (paper: 30).
    """

    # Paired demonstrator dataset (the agent dataset is lerobot-train's --dataset.repo_id).
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
    n_demo_frames: int = 4
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

    # Attention: 2 layers single-task, 3 multi-task (paper).
    n_attention_layers: int = 2
    # Heads per attention layer.
    n_attention_heads: int = 4
    # Softmax temperature dividing query-key dot products (paper: 16).
    attention_temperature: float = 16.0
    # "mosaic" (paper) or "full" spatio-temporal self-attention over all frames (T-OSIL-style baseline).
    attention_pattern: str = "mosaic"
    # Dropout on attention outputs.
    attention_dropout: float = 0.1

    # Per-frame embedding size fed to the action and inverse-dynamics heads.
    embed_dim: int = 256
    # Hidden width of the action / inverse-dynamics MLPs.
    head_hidden_dim: int = 256
    # Concatenate the normalised robot state to the embedding in the action head (the paper: images only).
    use_state: bool = False
    # Logistic mixture components per action dimension.
    n_mixtures: int = 3
    # Discretisation bins per action dimension over the normalised range [-1, 1].
    action_bins: int = 256
    # Inference: "mode" (mean of the most likely component) or "sample".
    action_sampling: str = "mode"

    # Weight of the behaviour-cloning loss (paper: 1).
    bc_loss_weight: float = 1.0
    # Weight of the inverse-dynamics loss (paper: 1).
    inverse_loss_weight: float = 1.0
    # Weight of the contrastive loss(es) (paper: 1).
    contrastive_loss_weight: float = 1.0

    # Temporal contrastive module: "off", "before" or "after" attention, or "both" (paper).
    contrastive: str = "both"
    # "infonce" (negatives = all other frames of the batch) or "byol" (no negatives).
    contrastive_objective: str = "infonce"
    # Positive: "window" (random within +-positive_window), "fixed" (exactly positive_window away), "same".
    contrastive_positive: str = "window"
    # k of the positive modes, in observation frames (frame_stride dataset frames each).
    positive_window: int = 2
    # Projector / predictor output width.
    contrastive_dim: int = 128
    # Projector / predictor hidden width.
    contrastive_hidden_dim: int = 512
    # InfoNCE temperature on the bilinear logits of L2-normalised vectors.
    contrastive_temperature: float = 0.1
    # Initial EMA momentum of the target encoder; rises to 1 with a cosine schedule.
    ema_momentum: float = 0.996
    # Steps over which the EMA momentum reaches 1 (default: lerobot-train's --steps).
    ema_total_steps: int | None = None

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

    def __post_init__(self):
        super().__post_init__()
        choices = {
            "contrastive": CONTRASTIVE_PLACEMENTS,
            "contrastive_positive": POSITIVE_MODES,
            "contrastive_objective": CONTRASTIVE_OBJECTIVES,
            "attention_pattern": ATTENTION_PATTERNS,
            "action_sampling": ACTION_SAMPLING,
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(
                    f"`{name}` must be one of {allowed}, got {getattr(self, name)!r}: "
                    f"pass e.g. --policy.{name}={allowed[0]}."
                )
        if self.n_demo_frames < 2:
            raise ValueError(
                f"`n_demo_frames` must be >= 2 (first and last frame), got {self.n_demo_frames}."
            )
        for name in (
            "train_obs_frames", "eval_obs_frames", "frame_stride", "action_chunk", "n_attention_layers",
            "n_attention_heads", "n_mixtures",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}.")
        if self.action_bins < 2:
            raise ValueError(f"`action_bins` must be >= 2, got {self.action_bins}.")
        if self.attention_temperature <= 0:
            raise ValueError(f"`attention_temperature` must be > 0, got {self.attention_temperature}.")
        if not 0.0 <= self.ema_momentum <= 1.0:
            raise ValueError(f"`ema_momentum` must be in [0, 1], got {self.ema_momentum}.")
        if self.contrastive_positive != "same" and self.positive_window < 1:
            raise ValueError(
                f"`positive_window` must be >= 1 for contrastive_positive={self.contrastive_positive!r}, "
                f"got {self.positive_window}; use --policy.contrastive_positive=same for k=0."
            )
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

    @property
    def contrastive_before(self) -> bool:
        return self.contrastive in ("before", "both")

    @property
    def contrastive_after(self) -> bool:
        return self.contrastive in ("after", "both")

    def get_optimizer_preset(self) -> AdamConfig:
        return AdamConfig(lr=self.optimizer_lr, weight_decay=self.optimizer_weight_decay)

    def get_scheduler_preset(self) -> None:
        return None

    @property
    def camera_key(self) -> str:
        """The visual feature the policy reads."""
        if self.image_key is not None:
            return self.image_key
        if not self.image_features:
            raise ValueError("MOSAIC needs one camera among the input features (e.g. observation.images.agentview).")
        return next(iter(self.image_features))

    def validate_features(self) -> None:
        if not self.image_features:
            raise ValueError(
                "MOSAIC needs a camera input (e.g. observation.images.agentview); the dataset has none."
            )
        if self.image_key is not None and self.image_key not in self.image_features:
            raise ValueError(
                f"`image_key`={self.image_key!r} is not a visual input feature; "
                f"available: {sorted(self.image_features)}."
            )
        if self.action_feature is None:
            raise ValueError("MOSAIC needs an `action` output feature.")
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
