"""The MOSAIC suite as a LeRobot environment: ``lerobot-eval --env.type=mosaic --env.task=door --policy.path=...``.

LeRobot's evaluation loop knows nothing of demonstrations, so the environment delivers one: every ``reset``
makes a fresh demonstration of the episode's variation by the demonstrator's expert (the Sawyer, on another
instance than the agent's) and returns it with every observation as ``demo``, (K, H, W, 3) uint8, the K frames
a MOSAIC policy conditions on (first, last, middle-segment centres). LeRobot's ``preprocess_observation`` passes
unknown keys through as ``observation.demo`` (float, channels last); the environment pre-processor returned by
:meth:`MosaicEnv.get_env_processors` turns it into (B, K, 3, H, W) in [0, 1], and the policy caches it on the
first ``select_action`` after ``reset()``.

Seeds and demonstrations are ``mosaic-eval``'s (one rule, :mod:`.seeds`; one source,
:class:`.demo_sources.ExpertDemoSource`): LeRobot resets episode ``e`` of every variation with
``s = --seed + e``; the wrapper puts the agent in instance ``s + 100000 * variation`` and has the expert
demonstrate instance ``s + 100000 * variation + 50000`` (``+ 5000`` per retry). So ``lerobot-eval --seed B``
and ``mosaic-eval --seed B`` run the same episodes and give the same numbers, episode by episode (their default
seeds differ, 1000 and 10^9: pass the same ``--seed`` to both). Each reset logs its seeds, and
``info["seed"]`` / ``info["demo_seed"]`` carry them.

Suites: ``--env.task=door`` gives one vector env per variation (LeRobot's per-task tables then show each
variation), ``--env.task=all`` every task's variations. The LeRobot plugin distribution
``lerobot_env_mosaic`` (installed by scripts/setup.sh) imports this module, which registers ``mosaic``.
"""

from __future__ import annotations

import logging
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
from lerobot.envs.utils import FreezeAfterEpisodeEnd
from lerobot.processor import ObservationProcessorStep, PolicyProcessorPipeline, ProcessorStepRegistry

from mosaic_data.constants import (
    ACTION_DIM,
    ACTION_KEY,
    CAMERA_KEY,
    DEMO_KEY,
    FPS,
    IMAGE_HEIGHT,
    IMAGE_WIDTH,
    N_DEMO_FRAMES,
    OBS_DEMO_KEY,
    STATE_DIM,
    STATE_KEY,
)

from .seeds import episode_seeds

if TYPE_CHECKING:
    from mosaic_data.demos import Demonstration

    from .demo_sources import ExpertDemoSource

logger = logging.getLogger(__name__)


class DemoConditionedEnv(gym.Wrapper):
    """A MOSAIC gym env whose observations carry a demonstration of its variation, made anew at every reset.

    ``reset(seed=s)`` takes ``s`` as the episode seed of the seed rule (:func:`.seeds.episode_seeds`): the agent's
    instance and the demonstrator's follow from it and the variation, and the demonstration comes from
    ``mosaic-eval``'s own source with its frame picking, so both front-ends run the same episodes.
    ``reset(seed=None)`` draws the episode seed from the environment's generator."""

    def __init__(self, env: gym.Env, demonstrator: str = "sawyer", demo_frames: int = N_DEMO_FRAMES) -> None:
        super().__init__(env)
        inner = env.unwrapped
        self.demonstrator = demonstrator
        self.demo_frames = demo_frames
        self._source: ExpertDemoSource | None = None  # its scenes are built at the first reset
        height, width = inner.image_height, inner.image_width
        self.observation_space = spaces.Dict(
            {**env.observation_space.spaces, DEMO_KEY: spaces.Box(0, 255, (demo_frames, height, width, 3), np.uint8)}
        )
        self.demonstration: Demonstration | None = None  # the current episode's
        self.episode_seed: int | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        from .demo_sources import policy_frames

        inner = self.env.unwrapped
        variation = inner.reset_variation(options)  # reset(options={"variation": k}) seeds as variation k
        if seed is None:  # gymnasium's autoreset, or a caller that does not seed
            seed = int(self.np_random.integers(0, 2**31 - 1))
        seeds = episode_seeds(int(seed), variation)
        observation, info = self.env.reset(seed=seeds.agent, options=options)
        demo = self._demo_source().demonstration(inner.task, variation, seeds.demo, policy_frames(self.demo_frames))
        self.demonstration, self.episode_seed = demo, seeds.episode
        logger.info(
            "%s variation %d, episode seed %d: agent instance %d, demonstration seed %d",
            inner.task, variation, seeds.episode, seeds.agent, demo.seed,
        )
        info = {**info, "episode_seed": seeds.episode, "demo_seed": demo.seed}
        return self._with_demo(observation), info

    @property
    def demo_seed(self) -> int | None:
        """The seed of the instance the current demonstration shows (after the expert's retries)."""
        return None if self.demonstration is None else self.demonstration.seed

    def _demo_source(self) -> ExpertDemoSource:
        """mosaic-eval's expert demo source, built on first use like the agent's scene (no GL context before a
        worker forks)."""
        if self._source is None:
            from .demo_sources import ExpertDemoSource

            inner = self.env.unwrapped
            self._source = ExpertDemoSource(self.demonstrator, (inner.image_height, inner.image_width))
        return self._source

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self._with_demo(observation), reward, terminated, truncated, info

    def _with_demo(self, observation: dict[str, Any]) -> dict[str, Any]:
        return {**observation, DEMO_KEY: None if self.demonstration is None else self.demonstration.frames}

    def close(self) -> None:
        if self._source is not None:
            self._source.close()
            self._source = None
        super().close()


def make_demo_conditioned_env(
    task: str, variation: int, robot: str, demonstrator: str, height: int, width: int, demo_frames: int,
    episode_length: int | None,
) -> gym.Env:
    """One sub-environment of a vector env (a module-level function, so that it pickles for async envs); its
    scenes are built at the first reset, in the process that runs it."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from mosaic_data.envs import MosaicGymEnv

    env = MosaicGymEnv(task, variation, robot, image_height=height, image_width=width, horizon=episode_length)
    # gymnasium's TimeLimit truncates the episode (and holds the ``_max_episode_steps`` LeRobot's loop reads).
    env = DemoConditionedEnv(gym.wrappers.TimeLimit(env, max_episode_steps=env.horizon), demonstrator, demo_frames)
    # LeRobot's own wrapper: once an episode ends, gymnasium's autoreset replays its last transition instead of
    # making a new instance and demonstration that the rollout throws away.
    return FreezeAfterEpisodeEnd(env)


@dataclass
@ProcessorStepRegistry.register(name="mosaic_demo_processor")
class MosaicDemoProcessorStep(ObservationProcessorStep):
    """``observation.demo`` from the environment (B, K, H, W, 3) 0..255 -> (B, K, 3, H, W) float in [0, 1]."""

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        demo = observation.get(OBS_DEMO_KEY)
        if demo is None:
            return observation
        demo = torch.as_tensor(demo)
        if demo.dim() == 4:
            demo = demo.unsqueeze(0)
        observation = dict(observation)
        observation[OBS_DEMO_KEY] = demo.permute(0, 1, 4, 2, 3).float() / 255.0
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
    fps: int = FPS
    episode_length: int | None = None
    robot: str = "panda"
    demonstrator: str = "sawyer"
    observation_height: int = IMAGE_HEIGHT
    observation_width: int = IMAGE_WIDTH
    demo_frames: int = N_DEMO_FRAMES
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION_KEY: ACTION_KEY,
            "agent_pos": STATE_KEY,
            "pixels/agentview": CAMERA_KEY,
        }
    )

    def __post_init__(self) -> None:
        self.features = {
            ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,)),
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
