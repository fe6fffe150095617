"""`--env.type=mosaic`: the demonstration travels through the environment into a MOSAIC policy (the real
`lerobot-eval` command runs in test_same_numbers.py, against mosaic-eval's numbers)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.helpers.evaluation import HEIGHT, WIDTH


def _env_config(**overrides):
    from pipelines.evaluation.lerobot_env import MosaicEnv

    options = dict(task="door", variations=[1], observation_height=HEIGHT, observation_width=WIDTH, episode_length=5)
    return MosaicEnv(**(options | overrides))


def test_the_environment_delivers_the_demonstration_to_the_policy(tiny_checkpoint):
    from lerobot.envs.utils import preprocess_observation
    from lerobot.policies.factory import make_pre_post_processors

    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    config = _env_config()
    envs = config.create_envs(n_envs=1)
    assert list(envs) == ["door"] and list(envs["door"]) == [1]
    env = envs["door"][1]
    try:
        observation, info = env.reset(seed=[7])
        demo = observation["demo"]
        assert demo.shape == (1, 4, HEIGHT, WIDTH, 3) and demo.dtype == np.uint8
        assert demo.std() > 5, "the demonstration frames are rendered, not blank"
        assert not np.array_equal(demo[0, 0], observation["pixels"]["agentview"][0]), "another instance than the agent's"
        assert env.call("_max_episode_steps")[0] == 5

        policy = MosaicPolicy.from_pretrained(tiny_checkpoint).eval()
        preprocessor, _ = make_pre_post_processors(policy.config, pretrained_path=str(tiny_checkpoint))
        env_preprocessor, _ = config.get_env_processors()
        batch = preprocess_observation(observation)
        batch["task"] = list(env.call("task_description"))
        batch = preprocessor(env_preprocessor(batch))
        assert batch["observation.demo"].shape == (1, 4, 3, HEIGHT, WIDTH)
        assert 0.0 <= batch["observation.demo"].min() and batch["observation.demo"].max() <= 1.0

        policy.reset()
        delivered = policy.select_action(batch)
        policy.reset()
        policy.set_demo(torch.from_numpy(demo[0]))
        direct = policy.select_action({k: v for k, v in batch.items() if k != "observation.demo"})
        torch.testing.assert_close(delivered, direct)
    finally:
        env.close()


def test_bad_env_options_are_one_line_errors():
    with pytest.raises(ValueError, match=r"unknown task 'laundry' \(--env.task\)"):
        _env_config(task="laundry").create_envs(1)
    with pytest.raises(ValueError, match=r"door has variations 0..3; got --env.variations \[9\]"):
        _env_config(variations=[9]).create_envs(1)
    with pytest.raises(ValueError, match="--env.variations applies to one task; drop it with --env.task all"):
        _env_config(task="all", variations=[0]).create_envs(1)
