"""LeRobot plugin: importing it registers every policy of the mosaic toolkit (`lerobot-train --policy.type=X`
with X any key of `POLICY_TYPES`)."""

from mosaic_policy import POLICY_TYPES, DamlConfig, LstmOsilConfig, MlpOsilConfig, MosaicConfig, TosilConfig

__all__ = ["POLICY_TYPES", "DamlConfig", "LstmOsilConfig", "MlpOsilConfig", "MosaicConfig", "TosilConfig"]
