"""Pre/post-processing pipelines of the tosil policy: the shared ones of every demo-conditioned policy."""

from ..common.processor_demo import make_demo_conditioned_pre_post_processors as make_tosil_pre_post_processors

__all__ = ["make_tosil_pre_post_processors"]
