"""Demonstration-conditioned policies for LeRobot: importing this package registers every policy type.

One folder per policy, as LeRobot does (`configuration_X.py`, `modeling_X.py`, `processor_X.py`):

- `mosaic/`: MOSAIC (`--policy.type=mosaic`), attention + contrastive learning (the paper's method);
- `tosil/`: T-OSIL (`--policy.type=tosil`), full spatio-temporal attention, inverse dynamics, point prediction;
- `lstm_osil/`: MOSAIC with an LSTM instead of attention (`--policy.type=lstm_osil`);
- `mlp_osil/`: an MLP task context from stacked demo features (`--policy.type=mlp_osil`);
- `daml/`: domain-adaptive meta-learning (`--policy.type=daml`).

`common/` holds what they share: the vision trunks, attention, action head, augmentation, encodings, the
demo-conditioning layer (paired demonstrator frames and loss weights inside lerobot-train) and the policy
interface (`set_demo`, `select_action`). Only the configurations load here; LeRobot's factory imports a
policy's modeling module when it builds one.
"""

import importlib

from .daml.configuration_daml import DamlConfig
from .lstm_osil.configuration_lstm_osil import LstmOsilConfig
from .mlp_osil.configuration_mlp_osil import MlpOsilConfig
from .mosaic.configuration_mosaic import MosaicConfig
from .tosil.configuration_tosil import TosilConfig

POLICY_TYPES: dict[str, str] = {
    "mosaic": "MOSAIC",
    "tosil": "T-OSIL",
    "lstm_osil": "LSTM",
    "mlp_osil": "MLP",
    "daml": "DAML",
}
"""Policy type -> the name of its row in the paper's Table I."""

__all__ = [
    "POLICY_TYPES",
    "DamlConfig",
    "LstmOsilConfig",
    "MlpOsilConfig",
    "MosaicConfig",
    "MosaicPolicy",
    "TosilConfig",
    "make_mosaic_pre_post_processors",
    "policy_class",
]


def policy_class(policy_type: str) -> type:
    """The policy class of a type of this package (its modeling module is imported now)."""
    module = importlib.import_module(f"{__name__}.{policy_type}.modeling_{policy_type}")
    config_name = {"mosaic": "Mosaic", "tosil": "Tosil", "lstm_osil": "LstmOsil", "mlp_osil": "MlpOsil", "daml": "Daml"}
    return getattr(module, f"{config_name[policy_type]}Policy")


def __getattr__(name):  # the model and processor modules load lazily, as LeRobot's factory does
    if name == "MosaicPolicy":
        from .mosaic.modeling_mosaic import MosaicPolicy

        return MosaicPolicy
    if name == "make_mosaic_pre_post_processors":
        from .mosaic.processor_mosaic import make_mosaic_pre_post_processors

        return make_mosaic_pre_post_processors
    raise AttributeError(name)
