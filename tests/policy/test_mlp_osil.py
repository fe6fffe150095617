"""The MLP baseline's own parts: its options, and a task context that depends on the order of the demonstration
frames. What every type does (shapes, learning, checkpoints, demo conditioning, acting as training computes) is
tested once for all in test_all_policies.py."""

import pytest
import torch
from tests.helpers.policy import HEIGHT, WIDTH, small_config

from mosaic_policy import MlpOsilConfig
from mosaic_policy.mlp_osil.modeling_mlp_osil import MlpOsilPolicy


def make_policy(**overrides) -> MlpOsilPolicy:
    torch.manual_seed(0)
    return MlpOsilPolicy(small_config(policy_type="mlp_osil", **overrides))


@pytest.mark.parametrize("field", ["n_context_layers", "context_hidden_dim", "context_dim"])
def test_config_rejects_bad_values_naming_the_field(field):
    with pytest.raises(ValueError, match=field):
        MlpOsilConfig(**{field: 0})


def test_the_task_context_depends_on_the_order_of_the_demonstration_frames():
    """The context MLP reads the demo frames' vectors concatenated in order (first, middle segments, last)."""
    policy = make_policy().eval()
    demo = torch.rand(1, policy.config.n_demo_frames, 3, HEIGHT, WIDTH)
    with torch.no_grad():
        forward, backward = (policy.encode_demo(frames) for frames in (demo, demo.flip(1)))
    assert forward.shape == (1, policy.config.context_dim)
    assert (forward - backward).abs().max() > 1e-4
