"""LeRobot plugin: importing it registers the MOSAIC suite as `lerobot-eval --env.type=mosaic`."""

from pipelines.evaluation.lerobot_env import MosaicEnv

__all__ = ["MosaicEnv"]
