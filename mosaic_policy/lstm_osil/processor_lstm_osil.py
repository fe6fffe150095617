"""Pre/post-processing pipelines of the lstm_osil policy: the shared ones of every demo-conditioned policy."""

from ..common.processor_demo import make_demo_conditioned_pre_post_processors as make_lstm_osil_pre_post_processors

__all__ = ["make_lstm_osil_pre_post_processors"]
