"""The conventions every part of the toolkit shares, in one place: feature keys, rates, sizes and seed rules.

Datasets, policies, the gym environments and both evaluation front-ends (``mosaic-eval`` and ``lerobot-eval
--env.type=mosaic``) read these names instead of repeating literals. Standard library only at import: policies
import it without loading the simulator, and command lines without loading torch.
"""

CAMERA_KEY = "observation.images.agentview"
"""The camera every dataset records and every policy reads (the paper's agent view)."""
STATE_KEY = "observation.state"
ACTION_KEY = "action"
DEMO_KEY = "demo"
"""The observation key under which an environment delivers the demonstration (``lerobot-eval --env.type=mosaic``)."""
OBS_DEMO_KEY = f"observation.{DEMO_KEY}"
"""The same after LeRobot's ``preprocess_observation``: (B, K, 3, H, W) float in [0, 1] once pre-processed."""
DEMO_FRAMES_KEY = "demo_frames"
"""Batch key of paired demonstrator frames in training, (B, K, 3, H, W) float in [0, 1]."""

FPS = 20
"""Control and recording rate (Hz) of every task and dataset."""
IMAGE_HEIGHT = 100
IMAGE_WIDTH = 180
"""The paper's camera size; datasets may be collected smaller (``--image-size``), a policy takes its dataset's."""
STATE_DIM = 10
STATE_NAMES = ("x", "y", "z", "r00", "r01", "r02", "r10", "r11", "r12", "gripper_opening")
"""The components of ``observation.state``: grip-site position, the first two rows of its rotation matrix, and the
gripper opening in [0, 1]."""
ACTION_DIM = 7
N_DEMO_FRAMES = 4
"""Frames of the demonstration a policy conditions on: first, last, one from each middle segment."""
VISION_BACKBONES = ("resnet18", "conv")
"""Values of ``--policy.vision_backbone``: the paper's ResNet-18 or the small strided CNN for CPU training."""


def policy_features(height: int = IMAGE_HEIGHT, width: int = IMAGE_WIDTH) -> dict:
    """The ``input_features`` and ``output_features`` of a policy trained on a mosaic-data dataset of ``height`` x
    ``width`` frames, as keyword arguments of a LeRobot policy config: ``MosaicConfig(**policy_features(h, w))``.
    LeRobot is imported when this is called, not when this module is."""
    from lerobot.configs import FeatureType, PolicyFeature

    return {
        "input_features": {
            CAMERA_KEY: PolicyFeature(type=FeatureType.VISUAL, shape=(3, height, width)),
            STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,)),
        },
        "output_features": {ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
    }


POLICY_TYPES: dict[str, str] = {
    "mosaic": "MOSAIC",
    "tosil": "T-OSIL",
    "lstm_osil": "LSTM",
    "mlp_osil": "MLP",
    "daml": "DAML",
}
"""Every policy type of ``mosaic_policy`` (``--policy.type``) -> the name of its row in the paper's Table I, in
Table I's column order. Here rather than in ``mosaic_policy`` so that command lines list the types without
importing torch; ``import mosaic_policy`` registers exactly these."""

# --- seeds -----------------------------------------------------------------------------------------------
# `mosaic-data collect` seeds training instances from 0 up; evaluation uses instances from EVAL_BASE_SEED.
# Evaluation episode e of variation v, from base seed B (mosaic-eval's --seed, lerobot-eval's --seed):
#   episode seed      s = B + e                       (what LeRobot's eval loop passes to env.reset)
#   agent instance      s + SEED_STRIDE_VARIATION * v
#   demonstrator        s + SEED_STRIDE_VARIATION * v + DEMO_SEED_OFFSET, then + DEMO_RETRY_STRIDE per expert retry
# so the demonstration always shows another instance than the agent's, and no two episodes share one.
EVAL_BASE_SEED = 1_000_000_000
SEED_STRIDE_VARIATION = 100_000
DEMO_SEED_OFFSET = 50_000
DEMO_RETRY_STRIDE = 5_000
MAX_EPISODES_PER_VARIATION = DEMO_RETRY_STRIDE
"""Episodes per variation for which the seed rule above gives distinct instances."""
