"""The LSTM baseline's own parts: its options, and its memory of an episode's query frames across a failed query.
What every type does (shapes, learning, checkpoints, demo conditioning, acting as training computes) is tested
once for all in test_all_policies.py."""

import pytest
import torch
from tests.helpers.policy import HEIGHT, IMAGE_KEY, WIDTH, small_config

from mosaic_policy import LstmOsilConfig
from mosaic_policy.lstm_osil.modeling_lstm_osil import LstmOsilPolicy


def make_policy(**overrides) -> LstmOsilPolicy:
    torch.manual_seed(0)
    return LstmOsilPolicy(small_config(policy_type="lstm_osil", **overrides))


@pytest.mark.parametrize("field", ["n_lstm_layers", "lstm_hidden_dim"])
def test_config_rejects_bad_values_naming_the_field(field):
    with pytest.raises(ValueError, match=field):
        LstmOsilConfig(**{field: 0})



def test_a_batch_that_changes_mid_episode_is_a_clear_error_that_leaves_the_episode_as_it_was():
    policy = make_policy().eval()
    demo = torch.rand(1, policy.config.n_demo_frames, 3, HEIGHT, WIDTH)
    frames = torch.rand(2, 2, 3, HEIGHT, WIDTH)  # two query frames of 2 environments

    def second_chunk(fail_in_between: bool) -> torch.Tensor:
        policy.set_demo(demo)
        policy.predict_action_chunk({IMAGE_KEY: frames[0]})
        if fail_in_between:
            with pytest.raises(ValueError, match="mid-episode"):  # the memory holds frames of 2 environments
                policy.predict_action_chunk({IMAGE_KEY: torch.rand(3, 3, HEIGHT, WIDTH)})
        return policy.predict_action_chunk({IMAGE_KEY: frames[1]})

    torch.testing.assert_close(second_chunk(fail_in_between=True), second_chunk(fail_in_between=False), atol=0, rtol=0)
