"""Configuration of the MOSAIC policy (multi-task one-shot imitation with self-attention and contrastive learning)."""

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig

from ..common.configuration_demo import DemoConditionedConfig

CONTRASTIVE_PLACEMENTS = ("off", "before", "after", "both")
POSITIVE_MODES = ("window", "fixed", "same")
CONTRASTIVE_OBJECTIVES = ("infonce", "byol")
ATTENTION_PATTERNS = ("mosaic", "full")
# Wrong demonstration of the wrong-demonstration loss (mosaic_policy/mosaic/wrong_demonstration.py).
WRONG_DEMO_PARTNERS = ("next", "nearest")
# What sets the action head's mixture weights: the frame's embedding (the paper) or the demonstration summary alone.
MIXTURE_WEIGHTS = ("frame", "demo")


@PreTrainedConfig.register_subclass("mosaic")
@dataclass
class MosaicConfig(DemoConditionedConfig):
    """Configuration of the MOSAIC policy (the shared options of every demo-conditioned policy, then MOSAIC's).

    The defaults are the paper's single-task settings. Options a user most likely changes: `demo_repo_id` (the
    demonstrator dataset paired with `--dataset.repo_id`), `n_attention_layers` (2 single-task, 3 multi-task)
    and `contrastive` (ablations). The contrastive positive lies within +-`positive_window` observation frames
    (0.5 s at the default time scale). `attention_pattern="full"` is T-OSIL's causal pattern inside MOSAIC (the
    attention ablation), acting with a memory of past frames. `demo_summary` adds the MLP baseline's ordered
    demonstration vector beside the attention, `variation_loss_weight` a supervised contrastive loss that groups
    a batch's demonstrations by variation, `wrong_demo_loss_weight` a loss that the recorded actions be likelier
    with the sample's own demonstration than with another variation's (none of the three in the paper). The EMA
    target's momentum reaches 1 over the run's `--steps` unless `ema_total_steps` says otherwise (fine-tuning a
    checkpoint starts a new schedule, `--resume` continues it).
    """

    # Attention: 2 layers single-task, 3 multi-task (paper).
    n_attention_layers: int = 2
    # Heads per attention layer.
    n_attention_heads: int = 4
    # Softmax temperature dividing query-key dot products (paper: 16).
    attention_temperature: float = 16.0
    # "mosaic" (paper) or "full": observation frames also attend to earlier observation frames (T-OSIL's pattern).
    attention_pattern: str = "mosaic"
    # Dropout on attention outputs.
    attention_dropout: float = 0.1
    # This project: also join each observation frame's embedding with an ordered summary of the demonstration (its
    # attended frames' vectors concatenated in time order, then an MLP: the MLP baseline's task context).
    demo_summary: bool = False
    # Width of the summary MLP's two hidden layers.
    summary_hidden_dim: int = 512
    # Size of the summary vector.
    summary_dim: int = 256
    # This project: weight of a supervised contrastive loss pulling together the projections of a batch's
    # demonstrations of one variation (LeRobot task string) and apart the others' (0: off, the paper; it uses
    # contrastive_dim, contrastive_hidden_dim and contrastive_temperature).
    variation_loss_weight: float = 0.0
    # This project: weight of a loss asking every observation frame which of two demonstrations explains its
    # recorded actions, its own or another variation's from the batch (0: off, the paper): it makes the action, not
    # only the demonstration stream, depend on the demonstration (mosaic_policy/mosaic/wrong_demonstration.py).
    wrong_demo_loss_weight: float = 0.0
    # Which wrong demonstration: "next" (the next batch sample of another variation) or "nearest" (the other
    # variation's demonstration the model finds most alike; on press_button a measured loss).
    wrong_demo_partner: str = "next"
    # This project: what sets the weights of the action head's logistic mixtures. "frame" (the paper): the head reads
    # them off each frame's embedding, like the means, so a frame can weight every variation's target alike whatever
    # the demonstration and act with the heaviest. "demo": a linear layer of the demonstration summary alone (needs
    # demo_summary), the same for the whole episode: the demonstration picks a component, the frame moves them.
    mixture_weights: str = "frame"

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
    # Steps over which the EMA momentum reaches 1 (default: the run's --steps).
    ema_total_steps: int | None = None

    def __post_init__(self):
        super().__post_init__()
        if self.contrastive in (False, "False"):  # the command line's `off` is YAML's false, decoded as "False"
            self.contrastive = "off"
        choices = {
            "contrastive": CONTRASTIVE_PLACEMENTS,
            "contrastive_positive": POSITIVE_MODES,
            "contrastive_objective": CONTRASTIVE_OBJECTIVES,
            "attention_pattern": ATTENTION_PATTERNS,
            "wrong_demo_partner": WRONG_DEMO_PARTNERS,
            "mixture_weights": MIXTURE_WEIGHTS,
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(
                    f"`{name}` must be one of {allowed}, got {getattr(self, name)!r}: "
                    f"pass e.g. --policy.{name}={allowed[0]}."
                )
        for name in ("n_attention_layers", "n_attention_heads", "summary_hidden_dim", "summary_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}.")
        for name in ("variation_loss_weight", "wrong_demo_loss_weight"):
            if getattr(self, name) < 0:
                raise ValueError(f"`{name}` must be >= 0 (0: off), got {getattr(self, name)}.")
        if self.mixture_weights == "demo" and not self.demo_summary:
            raise ValueError(
                "`mixture_weights=demo` reads the demonstration summary: add --policy.demo_summary=true."
            )
        if self.attention_temperature <= 0:
            raise ValueError(f"`attention_temperature` must be > 0, got {self.attention_temperature}.")
        if not 0.0 <= self.ema_momentum <= 1.0:
            raise ValueError(f"`ema_momentum` must be in [0, 1], got {self.ema_momentum}.")
        if self.contrastive_positive != "same" and self.positive_window < 1:
            raise ValueError(
                f"`positive_window` must be >= 1 for contrastive_positive={self.contrastive_positive!r}, "
                f"got {self.positive_window}; use --policy.contrastive_positive=same for k=0."
            )

    @property
    def contrastive_before(self) -> bool:
        return self.contrastive in ("before", "both")

    @property
    def contrastive_after(self) -> bool:
        return self.contrastive in ("after", "both")
