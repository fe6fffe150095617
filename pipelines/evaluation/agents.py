"""What acts in an evaluation rollout: a trained MOSAIC checkpoint, an untrained MOSAIC, or the scripted expert.

Every agent is driven by the same loop (:mod:`pipelines.evaluation.rollouts`): `start_episode` once with the
episode's demonstration, then `act` once per control step on a LeRobot-format observation. A policy goes through
exactly what `lerobot-eval` uses: LeRobot's `preprocess_observation`, the checkpoint's own pre-processor
(normalisation with the training set's statistics), `select_action`, and the post-processor.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from mosaic_data.demos import Demonstration
from mosaic_data.envs import MosaicGymEnv
from mosaic_data.tasks.base import ACTION_DIM, IMAGE_HEIGHT, IMAGE_WIDTH, STATE_DIM

BASELINES = ("expert", "untrained")
"""Sanity rows the evaluation can produce without a checkpoint."""

CAMERA_KEY = "observation.images.agentview"


class EvaluationError(ValueError):
    """Bad evaluation input (checkpoint, task, variations, demo dataset): the message names the fix."""


@dataclass(frozen=True)
class AgentSpec:
    """How to build an agent inside a worker process (plain data, so it pickles)."""

    kind: str  # "policy" (a checkpoint), "expert" or "untrained"
    label: str
    path: str | None = None
    image_hw: tuple[int, int] = (IMAGE_HEIGHT, IMAGE_WIDTH)
    record_attention: bool = False

    @property
    def needs_demo(self) -> bool:
        """The scripted expert reads the goal from the simulator, not from a demonstration."""
        return self.kind != "expert"

    @property
    def needs_camera(self) -> bool:
        return self.kind != "expert"


@dataclass
class AgentStep:
    """One action, and the policy's attention (per layer: (heads, h*w, h*w + demo tokens)) if asked for."""

    action: np.ndarray
    attention: list[np.ndarray] | None = None


class Agent(Protocol):
    spec: AgentSpec

    def start_episode(self, env: MosaicGymEnv, demo: Demonstration | None) -> None: ...

    def act(self, observation: dict[str, Any], env: MosaicGymEnv) -> AgentStep: ...


# ---------------------------------------------------------------------------------------------- checkpoints


def resolve_checkpoint(path: str | Path) -> Path:
    """The folder holding a MOSAIC policy's config.json: the path itself, its `pretrained_model`, or a
    lerobot-train run's `checkpoints/last/pretrained_model`."""
    path = Path(path).expanduser()
    if not path.exists():
        raise EvaluationError(f"checkpoint {str(path)!r} does not exist: pass the pretrained_model folder lerobot-train wrote")
    for candidate in (path, path / "pretrained_model", path / "checkpoints" / "last" / "pretrained_model"):
        config_file = candidate / "config.json"
        if config_file.is_file():
            break
    else:
        raise EvaluationError(
            f"{str(path)!r} is not a LeRobot policy checkpoint (no config.json): pass a folder such as "
            "outputs/train/<run>/checkpoints/last/pretrained_model"
        )
    try:
        policy_type = json.loads(config_file.read_text()).get("type")
    except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
        raise EvaluationError(f"{config_file} is not a readable policy config (corrupt JSON)") from None
    if policy_type != "mosaic":
        raise EvaluationError(
            f"{str(candidate)!r} holds a {policy_type!r} policy, not a MOSAIC policy: mosaic-eval evaluates "
            "checkpoints trained with --policy.type=mosaic"
        )
    if not (candidate / "model.safetensors").is_file():
        raise EvaluationError(f"{str(candidate)!r} has no model.safetensors: the checkpoint is incomplete")
    return candidate


def checkpoint_image_hw(path: Path, config: dict[str, Any]) -> tuple[int, int]:
    """(H, W) of the camera a checkpoint at ``path`` was trained on, from its config.json content."""
    features = config.get("input_features", {})
    camera = features.get(CAMERA_KEY) or next(
        (feature for feature in features.values() if feature.get("type") == "VISUAL"), None
    )
    if camera is None:
        raise EvaluationError(f"{path} has no camera input feature; mosaic-eval renders {CAMERA_KEY}")
    shape = camera["shape"]
    return int(shape[-2]), int(shape[-1])


# ---------------------------------------------------------------------------------------------- agents


def workspace_action_stats() -> dict[str, dict[str, torch.Tensor]]:
    """Action min/max = the environment's action box, so that an untrained head's [-1, 1] spans the workspace."""
    from mosaic_data.envs import ACTION_HIGH, ACTION_LOW

    return {"action": {"min": torch.from_numpy(ACTION_LOW.copy()), "max": torch.from_numpy(ACTION_HIGH.copy())}}


class PolicyAgent:
    """A MOSAIC policy with its LeRobot pre/post-processors (a checkpoint, or untrained for the sanity row)."""

    def __init__(self, spec: AgentSpec, policy, preprocessor, postprocessor) -> None:
        self.spec = spec
        self.policy = policy.eval()
        self.preprocessor = preprocessor
        self.postprocessor = postprocessor

    @classmethod
    def from_spec(cls, spec: AgentSpec) -> PolicyAgent:
        if spec.kind == "policy":
            return cls._from_checkpoint(spec)
        if spec.kind == "untrained":
            return cls._untrained(spec)
        raise EvaluationError(f"unknown policy agent kind {spec.kind!r}")

    @classmethod
    def _from_checkpoint(cls, spec: AgentSpec) -> PolicyAgent:
        from lerobot.policies.factory import make_pre_post_processors

        from mosaic_policy import MosaicConfig
        from mosaic_policy.modeling_mosaic import MosaicPolicy

        path = resolve_checkpoint(spec.path)
        config = MosaicConfig.from_pretrained(path)
        config.device = "cpu" if not torch.cuda.is_available() else config.device
        policy = MosaicPolicy.from_pretrained(path, config=config)
        preprocessor, postprocessor = make_pre_post_processors(
            config,
            pretrained_path=str(path),
            preprocessor_overrides={"device_processor": {"device": str(config.device)}},
            postprocessor_overrides={"device_processor": {"device": "cpu"}},
        )
        return cls(spec, policy, preprocessor, postprocessor)

    @classmethod
    def _untrained(cls, spec: AgentSpec) -> PolicyAgent:
        """MOSAIC at initialisation (the paper's "No Training" row); actions are scaled to the workspace box."""
        from lerobot.configs import FeatureType, PolicyFeature

        from mosaic_policy import MosaicConfig, make_mosaic_pre_post_processors
        from mosaic_policy.modeling_mosaic import MosaicPolicy

        height, width = spec.image_hw
        config = MosaicConfig(
            device="cpu",
            input_features={
                CAMERA_KEY: PolicyFeature(type=FeatureType.VISUAL, shape=(3, height, width)),
                "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,)),
            },
            output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
        )
        torch.manual_seed(0)  # the same untrained weights in every worker
        policy = MosaicPolicy(config)
        preprocessor, postprocessor = make_mosaic_pre_post_processors(config, dataset_stats=workspace_action_stats())
        return cls(spec, policy, preprocessor, postprocessor)

    def start_episode(self, env: MosaicGymEnv, demo: Demonstration | None) -> None:
        if demo is None:
            raise EvaluationError("a MOSAIC policy needs a demonstration for every episode")
        self.policy.reset()
        self.policy.set_demo(demo.frames)

    @torch.no_grad()
    def act(self, observation: dict[str, Any], env: MosaicGymEnv) -> AgentStep:
        from lerobot.envs.utils import preprocess_observation

        batch = preprocess_observation(observation)
        batch["task"] = [env.task_description]
        batch = self.preprocessor(batch)
        if self.spec.record_attention:
            action, weights = self.policy.predict_with_attention(batch)
            attention = [layer[0, :, 0].float().cpu().numpy() for layer in weights]
        else:
            action, attention = self.policy.select_action(batch), None
        action = self.postprocessor(action)
        return AgentStep(action=action[0].cpu().numpy().astype(np.float64), attention=attention)


class ExpertAgent:
    """The task's scripted expert for the agent's robot, acting through the same loop (the sanity row)."""

    def __init__(self, spec: AgentSpec) -> None:
        self.spec = spec
        self._expert = None

    def start_episode(self, env: MosaicGymEnv, demo: Demonstration | None) -> None:
        from mosaic_data.experts import make_expert

        self._expert = make_expert(env.task_env)

    def act(self, observation: dict[str, Any], env: MosaicGymEnv) -> AgentStep:
        return AgentStep(action=np.asarray(self._expert.act(), dtype=np.float64))


def build_agent(spec: AgentSpec) -> Agent:
    return ExpertAgent(spec) if spec.kind == "expert" else PolicyAgent.from_spec(spec)
