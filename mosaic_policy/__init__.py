"""MOSAIC policies for LeRobot: importing this package registers `--policy.type=mosaic`.

Files: configuration_mosaic.py (options), modeling_mosaic.py (policy), processor_mosaic.py (normalisation);
shared blocks: resnet_trunk.py, attention.py, contrastive.py, discretized_logistic.py, augmentation.py,
paired_sampling.py (demonstrator frames for lerobot-train).
"""

from .configuration_mosaic import MosaicConfig

__all__ = ["MosaicConfig", "MosaicPolicy", "make_mosaic_pre_post_processors"]


def __getattr__(name):  # the model and processor modules load lazily, as LeRobot's factory does
    if name == "MosaicPolicy":
        from .modeling_mosaic import MosaicPolicy

        return MosaicPolicy
    if name == "make_mosaic_pre_post_processors":
        from .processor_mosaic import make_mosaic_pre_post_processors

        return make_mosaic_pre_post_processors
    raise AttributeError(name)
