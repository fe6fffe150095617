"""LeRobot plugin: importing it registers every policy of the mosaic toolkit (`lerobot-train --policy.type=X`
with X in mosaic, tosil, lstm_osil, mlp_osil, daml)."""

from mosaic_policy import POLICY_TYPES, DamlConfig, LstmOsilConfig, MlpOsilConfig, MosaicConfig, TosilConfig

__all__ = ["POLICY_TYPES", "DamlConfig", "LstmOsilConfig", "MlpOsilConfig", "MosaicConfig", "TosilConfig"]
