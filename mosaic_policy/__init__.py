"""Demonstration-conditioned policies for LeRobot: importing this package registers every policy type
(`POLICY_TYPES`, defined torch-free in `mosaic_data.constants`).

One folder per policy, as LeRobot does (`configuration_X.py`, `modeling_X.py`, `processor_X.py`):

- `mosaic/`: MOSAIC (`--policy.type=mosaic`), attention + contrastive learning (the paper's method);
- `tosil/`: T-OSIL (`--policy.type=tosil`), full spatio-temporal attention, inverse dynamics, point prediction;
- `lstm_osil/`: MOSAIC with an LSTM instead of attention (`--policy.type=lstm_osil`);
- `mlp_osil/`: an MLP task context from stacked demo features (`--policy.type=mlp_osil`);
- `daml/`: domain-adaptive meta-learning (`--policy.type=daml`).

`common/` holds what they share: the model skeleton (vision trunk, frame embedding, action and inverse-dynamics
heads; each policy adds its task context), attention, augmentation, encodings, the demo-conditioning layer
(paired demonstrator frames and loss weights inside lerobot-train) and the policy interface (`set_demo`,
`select_action`). Only the configurations load here; LeRobot's factory imports a policy's modeling module when
it builds one.
"""

from mosaic_data.constants import POLICY_TYPES

from .daml.configuration_daml import DamlConfig
from .lstm_osil.configuration_lstm_osil import LstmOsilConfig
from .mlp_osil.configuration_mlp_osil import MlpOsilConfig
from .mosaic.configuration_mosaic import MosaicConfig
from .tosil.configuration_tosil import TosilConfig

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
    """The policy class of a type of this package, found as LeRobot's factory finds it (importing its modeling
    module on the call)."""
    from lerobot.policies.factory import get_policy_class

    if policy_type not in POLICY_TYPES:
        raise ValueError(f"unknown policy type {policy_type!r}: choose from {', '.join(POLICY_TYPES)}")
    return get_policy_class(policy_type)


def __getattr__(name):  # the model and processor modules load lazily, as LeRobot's factory does
    if name == "MosaicPolicy":
        from .mosaic.modeling_mosaic import MosaicPolicy

        return MosaicPolicy
    if name == "make_mosaic_pre_post_processors":
        from .mosaic.processor_mosaic import make_mosaic_pre_post_processors

        return make_mosaic_pre_post_processors
    raise AttributeError(name)
