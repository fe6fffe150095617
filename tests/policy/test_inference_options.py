"""Options of the shared policy interface: the state components the head reads, and temporal ensembling."""

import math

import pytest
import torch

from tests.helpers.policy import HEIGHT, IMAGE_KEY, WIDTH, random_batch, small_config


def _policy(**overrides):
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    return MosaicPolicy(small_config(**overrides))


def test_the_head_reads_only_the_chosen_state_components():
    policy = _policy(use_state=True, state_components=["gripper_opening"])
    assert policy.model.action_head.mlp[0].in_features == policy.config.embed_dim + 1
    loss, _ = policy.train().forward(random_batch(policy.config, batch_size=2))
    assert torch.isfinite(loss)
    policy.eval().set_demo(torch.rand(policy.config.n_demo_frames, 3, HEIGHT, WIDTH))
    image, state = torch.rand(1, 3, HEIGHT, WIDTH), torch.zeros(1, 10)
    moved, opened = state.clone(), state.clone()
    moved[0, :3] = 0.5  # the grip site's position: not read
    opened[0, 9] = 1.0  # the gripper opening: read
    with torch.no_grad():
        means = [policy.chunk_distribution(image, s, policy._context).means for s in (state, moved, opened)]
    assert torch.equal(means[0], means[1]) and not torch.equal(means[0], means[2])


def test_an_unknown_state_component_names_the_choices():
    with pytest.raises(ValueError, match="choose among x, y, z, .*gripper_opening"):
        small_config(use_state=True, state_components=["gripper"])


def test_temporal_ensembling_averages_every_chunk_that_covers_the_step():
    coeff = 0.5
    policy = _policy(action_chunk=3, temporal_ensemble_coeff=coeff).eval()
    policy.set_demo(torch.rand(policy.config.n_demo_frames, 3, HEIGHT, WIDTH))
    chunks = [torch.full((1, 3, 7), 10.0 * q) + torch.arange(3.0)[None, :, None] for q in range(5)]
    queries = iter(chunks)
    policy._act = lambda batch: next(queries)  # the chunk the policy would give at each step
    observation = {IMAGE_KEY: torch.rand(1, 3, HEIGHT, WIDTH)}
    actions = [policy.select_action(observation)[0, 0].item() for _ in range(5)]
    weights = [math.exp(-coeff * i) for i in range(3)]  # oldest first
    assert actions[0] == 0.0  # one chunk: its first target
    assert actions[1] == pytest.approx((weights[0] * 1.0 + weights[1] * 10.0) / sum(weights[:2]))
    # from the third step on, three chunks cover each step: made 2, 1 and 0 steps ago
    expected = (weights[0] * (10.0 * 2 + 2) + weights[1] * (10.0 * 3 + 1) + weights[2] * (10.0 * 4)) / sum(weights)
    assert actions[4] == pytest.approx(expected)
    policy.reset()
    assert len(policy._action_queue) == 0  # a new episode forgets the old chunks


def test_n_action_steps_hands_out_the_first_targets_of_each_chunk_then_queries_again():
    policy = _policy(action_chunk=4, n_action_steps=2).eval()
    policy.set_demo(torch.rand(policy.config.n_demo_frames, 3, HEIGHT, WIDTH))
    chunks = [torch.full((1, 4, 7), 10.0 * q) + torch.arange(4.0)[None, :, None] for q in range(3)]
    queries = iter(chunks)
    policy._act = lambda batch: next(queries)
    observation = {IMAGE_KEY: torch.rand(1, 3, HEIGHT, WIDTH)}
    actions = [policy.select_action(observation)[0, 0].item() for _ in range(6)]
    assert actions == [0.0, 1.0, 10.0, 11.0, 20.0, 21.0]  # a new chunk every 2 steps, its targets 0 and 1


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"action_chunk": 4, "n_action_steps": 5}, "between 1 and `action_chunk` \\(4\\)"),
        ({"action_chunk": 4, "n_action_steps": 0}, "between 1 and `action_chunk`"),
        ({"action_chunk": 4, "n_action_steps": 2, "temporal_ensemble_coeff": 0.01}, "pass one of them"),
    ],
)
def test_n_action_steps_out_of_range_names_the_fix(overrides, message):
    with pytest.raises(ValueError, match=message):
        small_config(**overrides)
