"""`weight_average_decay`: every policy type keeps an exponential moving average of its weights, steps it in
update() (what lerobot-train calls after each optimizer step), acts with it outside training, and saves and loads it
beside the trained weights."""

import pytest
import torch
from tests.helpers.policy import HEIGHT, IMAGE_KEY, POLICY_TYPES, WIDTH, random_batch, small_config

from mosaic_policy.common.weight_average import WARMUP_OFFSET, warmed_up_decay


def _policy(policy_type: str, **overrides):
    from lerobot.policies.factory import get_policy_class

    import mosaic_policy  # noqa: F401  (registers the types)

    torch.manual_seed(0)
    return get_policy_class(policy_type)(small_config(policy_type=policy_type, **overrides))


def _train_step(policy, seed: int = 0) -> None:
    optimizer = torch.optim.SGD(policy.get_optim_params(), lr=0.5)
    loss, _ = policy.train().forward(random_batch(policy.config, batch_size=2, seed=seed))
    loss.backward()
    optimizer.step()
    optimizer.zero_grad()
    policy.update()


def _first_action(policy) -> torch.Tensor:
    policy.reset()
    policy.set_demo(torch.rand(policy.config.n_demo_frames, 3, HEIGHT, WIDTH, generator=torch.Generator().manual_seed(1)))
    image = torch.rand(1, 3, HEIGHT, WIDTH, generator=torch.Generator().manual_seed(2))
    return policy.select_action({IMAGE_KEY: image, "observation.state": torch.zeros(1, 10)})


def test_the_decay_warms_up_to_the_configured_one():
    assert warmed_up_decay(0, 0.995) == pytest.approx(1 / WARMUP_OFFSET)
    assert warmed_up_decay(10, 0.995) == pytest.approx(11 / 20)
    assert warmed_up_decay(10_000, 0.995) == 0.995


def test_a_decay_outside_0_1_names_the_fix():
    with pytest.raises(ValueError, match=r"weight_average_decay.*--policy.weight_average_decay=0.998"):
        small_config(weight_average_decay=1.0)


@pytest.mark.parametrize("policy_type", POLICY_TYPES)
def test_the_average_follows_training_and_the_policy_acts_with_it(policy_type, tmp_path):
    policy = _policy(policy_type, weight_average_decay=0.5)
    trained_ids = {id(p) for p in policy.get_optim_params()}
    assert not any(id(p) in trained_ids for p in policy.averaged_model.parameters())  # no optimizer trains it
    before = {name: p.detach().clone() for name, p in policy.model.named_parameters() if p.requires_grad}
    _train_step(policy)
    decay = warmed_up_decay(0, 0.5)
    averaged = dict(policy.averaged_model.named_parameters())
    for name, trained in policy.model.named_parameters():
        if name in before:  # MOSAIC's EMA target projectors inside the model move after the average's step
            torch.testing.assert_close(averaged[name], decay * before[name] + (1 - decay) * trained.detach())
    _train_step(policy, seed=1)
    assert int(policy.weight_average_updates) == 2
    assert policy.train().acting_model is policy.model
    assert policy.eval().acting_model is policy.averaged_model

    averaged = _first_action(policy)
    policy.config.act_with_weight_average = False  # the same checkpoint, acting with its trained weights
    trained = _first_action(policy)
    assert not torch.equal(averaged, trained), policy_type
    policy.config.act_with_weight_average = True

    policy.save_pretrained(tmp_path)
    loaded = type(policy).from_pretrained(tmp_path).eval()
    for name, tensor in policy.state_dict().items():
        assert torch.equal(loaded.state_dict()[name], tensor), name
    torch.testing.assert_close(_first_action(loaded), averaged)


def test_without_a_decay_there_is_no_average_and_the_trained_model_acts():
    policy = _policy("mosaic").eval()
    assert policy.averaged_model is None and policy.acting_model is policy.model
    assert not any(name.startswith("averaged_model.") for name in policy.state_dict())
