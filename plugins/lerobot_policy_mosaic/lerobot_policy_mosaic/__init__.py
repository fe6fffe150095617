"""LeRobot plugin: importing it registers the MOSAIC policy (`lerobot-train --policy.type=mosaic`)."""

from mosaic_policy import MosaicConfig

__all__ = ["MosaicConfig"]
