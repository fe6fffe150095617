"""The demonstration decides the action: a toy problem where only the demo tells which variation to do."""

import torch
from tests.helpers.policy import HEIGHT, IMAGE_KEY, WIDTH, small_config

from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy


def _demo(variation: int, n: int, generator: torch.Generator) -> torch.Tensor:
    """(n, 4, 3, H, W) demo frames: variation 0 is reddish, variation 1 bluish, with noise."""
    frames = 0.3 + 0.1 * torch.rand(n, 4, 3, HEIGHT, WIDTH, generator=generator)
    frames[:, :, 0 if variation == 0 else 2] += 0.5
    return frames


def _observations(n: int, generator: torch.Generator) -> torch.Tensor:
    """Observation frames carry no hint of the variation."""
    return 0.4 + 0.2 * torch.rand(n, 1, 3, HEIGHT, WIDTH, generator=generator)


def test_prediction_follows_the_demonstrated_variation():
    torch.manual_seed(0)
    config = small_config(
        train_obs_frames=1,
        n_attention_layers=1,
        contrastive="off",
        augment=False,
        use_state=False,
        optimizer_lr=3e-4,
        # One component: a mixture can first fit both variations' actions as two modes and only later learn
        # to read the demo (seen here with 3 components in 100 steps); one component must read it at once.
        n_mixtures=1,
    )
    policy = MosaicPolicy(config).train()
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=config.optimizer_lr)
    g = torch.Generator().manual_seed(0)
    target = {0: 0.6, 1: -0.6}
    for _ in range(90):
        variations = [0, 1] * 4
        demo = torch.cat([_demo(v, 1, g) for v in variations])
        actions = torch.zeros(8, 1, 7)
        actions[:, 0, 0] = torch.tensor([target[v] for v in variations])
        batch = {
            IMAGE_KEY: _observations(8, g),
            "action": actions,
            "demo_frames": demo,
            "task": [f"variation {v}" for v in variations],
        }
        loss, _ = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    policy.eval()
    observation = {IMAGE_KEY: _observations(4, g)[:, 0]}
    predictions = {}
    for variation in (0, 1):
        policy.reset()
        policy.set_demo(_demo(variation, 1, g)[0])
        predictions[variation] = policy.select_action(observation)[:, 0]
    assert (predictions[0] > 0.2).all(), predictions
    assert (predictions[1] < -0.2).all(), predictions
