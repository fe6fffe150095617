"""The MOSAIC suite as a LeRobot environment: ``lerobot-eval --env.type=mosaic --env.task=door --policy.path=...``.

LeRobot's evaluation loop knows nothing of demonstrations, so the environment delivers one: every ``reset``
makes a fresh demonstration of the episode's variation by the demonstrator's expert (the Sawyer, on instance
``seed + 50000``, another instance than the agent's) and returns it with every observation as ``demo``,
(K, H, W, 3) uint8, the K frames a MOSAIC policy conditions on (first, last, middle-segment centres). LeRobot's
``preprocess_observation`` passes unknown keys through as ``observation.demo`` (float, channels last); the
environment pre-processor returned by :meth:`MosaicEnv.get_env_processors` turns it into (B, K, 3, H, W) in
[0, 1], and the policy caches it on the first ``select_action`` after ``reset()``.

Suites: ``--env.task=door`` gives one vector env per variation (LeRobot's per-task tables then show each
variation), ``--env.task=all`` every task's variations. The LeRobot plugin distribution
``lerobot_env_mosaic`` (installed by scripts/setup.sh) imports this module, which registers ``mosaic``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.processor import ObservationProcessorStep, PolicyProcessorPipeline, ProcessorStepRegistry
from lerobot.utils.constants import ACTION, OBS_STATE

if TYPE_CHECKING:
    from mosaic_data.envs import MosaicGymEnv
    from mosaic_data.tasks.base import MosaicTaskEnv

DEMO_KEY = "demo"
OBS_DEMO = f"observation.{DEMO_KEY}"
DEMO_SEED_OFFSET = 50_000


class DemoConditionedEnv(gym.Wrapper):
    """A MOSAIC gym env whose observations carry a demonstration of its variation, made anew at every reset."""

    def __init__(self, env: gym.Env, demonstrator: str = "sawyer", demo_frames: int = 4) -> None:
        super().__init__(env)
        inner = env.unwrapped
        self.demonstrator = demonstrator
        self.demo_frames = demo_frames
        self._demo_env: MosaicTaskEnv | None = None  # the demonstrator's scene, built at the first reset
        height, width = inner.image_height, inner.image_width
        self.observation_space = spaces.Dict(
            {**env.observation_space.spaces, DEMO_KEY: spaces.Box(0, 255, (demo_frames, height, width, 3), np.uint8)}
        )
        self._demo: np.ndarray | None = None
        self.demo_seed: int | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        from mosaic_data.demos import record_demonstration
        from mosaic_policy.paired_sampling import demo_frame_indices

        observation, info = self.env.reset(seed=seed, options=options)
        inner = self.env.unwrapped
        demo_env = self._demonstrator_scene(inner)
        if demo_env.variation_index != inner.variation:  # reset(options={"variation": k}) switched the agent's
            demo_env.set_variation(inner.variation)
        demo = record_demonstration(
            demo_env, inner.task_env.instance_seed + DEMO_SEED_OFFSET,
            lambda length: demo_frame_indices(length, self.demo_frames),
        )
        self._demo, self.demo_seed = demo.frames, demo.seed
        info = {**info, "demo_seed": demo.seed}
        return self._with_demo(observation), info

    def _demonstrator_scene(self, inner: MosaicGymEnv) -> MosaicTaskEnv:
        """The demonstrator's scene, built on first use like the agent's (no GL context before a worker forks)."""
        if self._demo_env is None:
            from mosaic_data.tasks import make_task_env

            self._demo_env = make_task_env(
                inner.task, inner.variation, self.demonstrator,
                image_height=inner.image_height, image_width=inner.image_width,
            )
        return self._demo_env

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self._with_demo(observation), reward, terminated, truncated, info

    def _with_demo(self, observation: dict[str, Any]) -> dict[str, Any]:
        return {**observation, DEMO_KEY: self._demo}

    def close(self) -> None:
        if self._demo_env is not None:
            self._demo_env.close()
            self._demo_env = None
        super().close()


def make_demo_conditioned_env(
    task: str, variation: int, robot: str, demonstrator: str, height: int, width: int, demo_frames: int,
    episode_length: int | None,
) -> DemoConditionedEnv:
    """One sub-environment of a vector env (a module-level function, so that it pickles for async envs); its
    scenes are built at the first reset, in the process that runs it."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from mosaic_data.envs import MosaicGymEnv

    env = MosaicGymEnv(task, variation, robot, image_height=height, image_width=width, horizon=episode_length)
    # gymnasium's TimeLimit truncates the episode (and holds the ``_max_episode_steps`` LeRobot's loop reads).
    return DemoConditionedEnv(gym.wrappers.TimeLimit(env, max_episode_steps=env.horizon), demonstrator, demo_frames)


@dataclass
@ProcessorStepRegistry.register(name="mosaic_demo_processor")
class MosaicDemoProcessorStep(ObservationProcessorStep):
    """``observation.demo`` from the environment (B, K, H, W, 3) 0..255 -> (B, K, 3, H, W) float in [0, 1]."""

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        demo = observation.get(OBS_DEMO)
        if demo is None:
            return observation
        demo = torch.as_tensor(demo)
        if demo.dim() == 4:
            demo = demo.unsqueeze(0)
        observation = dict(observation)
        observation[OBS_DEMO] = demo.permute(0, 1, 4, 2, 3).float() / 255.0
        return observation

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features


@EnvConfig.register_subclass("mosaic")
@dataclass
class MosaicEnv(EnvConfig):
    """``--env.type=mosaic``: the MOSAIC suite, a Panda agent, demonstrations by the Sawyer's expert.

    task: a task of the suite (``mosaic-data tasks``) or "all"; variations: a subset of the task's variations
    (default all); episode_length: steps per episode (default: the task's horizon); observation size: must be
    the policy's camera size; demo_frames: frames of the demonstration delivered with every observation.
    """

    task: str = "door"
    variations: list[int] | None = None
    fps: int = 20
    episode_length: int | None = None
    robot: str = "panda"
    demonstrator: str = "sawyer"
    observation_height: int = 100
    observation_width: int = 180
    demo_frames: int = 4
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION: ACTION,
            "agent_pos": OBS_STATE,
            "pixels/agentview": "observation.images.agentview",
        }
    )

    def __post_init__(self) -> None:
        from mosaic_data.tasks.base import ACTION_DIM, STATE_DIM

        self.features = {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,)),
            "pixels/agentview": PolicyFeature(
                type=FeatureType.VISUAL, shape=(self.observation_height, self.observation_width, 3)
            ),
        }

    @property
    def gym_kwargs(self) -> dict:
        return {
            "robot": self.robot,
            "demonstrator": self.demonstrator,
            "height": self.observation_height,
            "width": self.observation_width,
            "demo_frames": self.demo_frames,
            "episode_length": self.episode_length,
        }

    def suite(self) -> dict[str, list[int]]:
        """Task -> variations to evaluate, checked with one-line errors."""
        from mosaic_data.tasks import select_variations

        variations = None if self.variations is None else list(self.variations)
        return select_variations(self.task, variations, task_option="--env.task", variations_option="--env.variations")

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        from gymnasium.vector import AutoresetMode

        env_cls = gym.vector.AsyncVectorEnv if (use_async_envs and n_envs > 1) else gym.vector.SyncVectorEnv
        extra = {"context": "spawn"} if env_cls is gym.vector.AsyncVectorEnv else {}
        envs: dict[str, dict[int, gym.vector.VectorEnv]] = {}
        for task, variations in self.suite().items():
            envs[task] = {}
            for variation in variations:
                make_one = partial(make_demo_conditioned_env, task, variation, **self.gym_kwargs)
                envs[task][variation] = env_cls(
                    [make_one for _ in range(n_envs)], autoreset_mode=AutoresetMode.SAME_STEP, **extra
                )
        return envs

    def get_env_processors(self):
        return PolicyProcessorPipeline(steps=[MosaicDemoProcessorStep()]), PolicyProcessorPipeline(steps=[])
