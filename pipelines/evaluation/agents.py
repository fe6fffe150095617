"""What acts in an evaluation rollout: a checkpoint of any LeRobot policy type (MOSAIC, ACT, ...), an untrained
MOSAIC, or the scripted expert.

Every agent is driven by the same loop (:mod:`pipelines.evaluation.rollouts`): `start_episode` once with the
episode's demonstration, then `act` once per control step on a LeRobot-format observation. A policy goes through
exactly what `lerobot-eval` uses: LeRobot's factory for its type, `preprocess_observation`, the checkpoint's own
pre-processor (normalisation with the training set's statistics), `select_action` (which keeps its own action
queue for policies that predict chunks, like ACT), and the post-processor. Only a policy with a `set_demo` method
(MOSAIC) is shown the demonstration; any other one acts without it, so it cannot know which variation to do.
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import torch

from mosaic_data.constants import (
    ACTION_DIM,
    ACTION_KEY,
    CAMERA_KEY,
    IMAGE_HEIGHT,
    IMAGE_WIDTH,
    STATE_DIM,
    STATE_KEY,
    policy_features,
)

from .options import BASELINES, EvaluationError  # noqa: F401  (defined there: light enough for --help)

if TYPE_CHECKING:  # annotations only: the simulator loads when an episode needs it
    from mosaic_data.demos import Demonstration
    from mosaic_data.envs import MosaicGymEnv

PROVIDED = f"{CAMERA_KEY} (3xHxW, any size) and {STATE_KEY} ({STATE_DIM},)"
"""What the MOSAIC environments give a policy, for error messages."""


CHECKPOINT_FILES = ("config.json", "model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json")
"""What lerobot-train writes into every pretrained_model folder and loading a policy reads (plus the processors'
state files that the two processor files name)."""
INCOMPLETE_FIX = "the checkpoint is incomplete: copy the whole pretrained_model folder lerobot-train wrote, or retrain"


@dataclass(frozen=True)
class AgentSpec:
    """How to build an agent inside a worker process (plain data, so it pickles)."""

    kind: str  # "policy" (a checkpoint), "expert" or "untrained"
    label: str
    path: str | None = None
    image_hw: tuple[int, int] = (IMAGE_HEIGHT, IMAGE_WIDTH)
    record_attention: bool = False
    takes_demo: bool = True  # a policy with `set_demo`; one without acts blind to the demonstration
    expert_variation: int | None = None  # the expert pursues this variation, not the episode's (a demo-blind agent)
    policy_options: tuple[tuple[str, Any], ...] = ()  # (field, value) set on the checkpoint's config (--policy.X)

    @property
    def needs_demo(self) -> bool:
        """The scripted expert reads the goal from the simulator, and a policy without `set_demo` cannot use one."""
        return self.kind != "expert" and self.takes_demo

    @property
    def needs_camera(self) -> bool:
        return self.kind != "expert"


@dataclass
class AgentStep:
    """One action, and the policy's attention (per layer: (heads, h*w, h*w + demo tokens)) if asked for."""

    action: np.ndarray
    attention: list[np.ndarray] | None = None
    phase: str | None = None  # the scripted expert's phase when it chose the action; None for a policy


class Agent(Protocol):
    spec: AgentSpec

    def start_episode(self, env: MosaicGymEnv, demo: Demonstration | None) -> None: ...

    def act(self, observation: dict[str, Any], env: MosaicGymEnv) -> AgentStep: ...


# ---------------------------------------------------------------------------------------------- checkpoints


def resolve_checkpoint(path: str | Path) -> Path:
    """The folder holding a LeRobot policy's config.json: the path itself, its `pretrained_model`, or a
    lerobot-train run's `checkpoints/last/pretrained_model`."""
    path = Path(path).expanduser()
    if not path.exists():
        raise EvaluationError(f"checkpoint {str(path)!r} does not exist: pass the pretrained_model folder lerobot-train wrote")
    for candidate in (path, path / "pretrained_model", path / "checkpoints" / "last" / "pretrained_model"):
        config_file = candidate / "config.json"
        if config_file.is_file():
            break
    else:
        if any((path / name).exists() for name in CHECKPOINT_FILES):
            raise EvaluationError(
                f"{path / 'config.json'} is missing (no config.json beside the checkpoint's other files): "
                f"{INCOMPLETE_FIX}"
            )
        raise EvaluationError(
            f"{str(path)!r} is not a LeRobot policy checkpoint (no config.json): pass a folder such as "
            "outputs/train/<run>/checkpoints/last/pretrained_model"
        )
    read_config(candidate)
    if not (candidate / "model.safetensors").is_file():
        raise EvaluationError(f"{candidate / 'model.safetensors'} is missing: {INCOMPLETE_FIX}")
    return candidate


def read_config(checkpoint: Path) -> dict[str, Any]:
    """config.json of a resolved checkpoint, with a policy type."""
    config_file = checkpoint / "config.json"
    try:
        config = json.loads(config_file.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise EvaluationError(f"{config_file} is not a readable policy config (corrupt JSON): {INCOMPLETE_FIX}") from None
    if not isinstance(config, dict) or not isinstance(config.get("type"), str):
        raise EvaluationError(f"{config_file} names no policy type: pass a checkpoint written by lerobot-train")
    return config


def check_checkpoint_files(checkpoint: Path) -> None:
    """Every file loading the policy reads is there and whole, checked before any rollout (a checkpoint copied in
    part, or cut short by a full disk, would otherwise fail in a worker after the evaluation started): the weights,
    both processor pipelines and the state files they name; a safetensors file's header must parse and its tensors
    must end exactly where the file does."""
    for name in CHECKPOINT_FILES[2:]:
        pipeline_file = checkpoint / name
        if not pipeline_file.is_file():
            raise EvaluationError(f"{pipeline_file} is missing: {INCOMPLETE_FIX}")
        try:
            steps = json.loads(pipeline_file.read_text()).get("steps", [])
            state_files = [step["state_file"] for step in steps if isinstance(step, dict) and step.get("state_file")]
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError, TypeError):
            raise EvaluationError(f"{pipeline_file} is not a readable processor file (corrupt JSON): {INCOMPLETE_FIX}") from None
        for state_file in state_files:
            _check_safetensors(checkpoint / state_file)
    _check_safetensors(checkpoint / "model.safetensors")


def _check_safetensors(path: Path) -> None:
    """A safetensors file: 8 bytes of header length, a JSON header, then the tensors' bytes to the file's end."""
    if not path.is_file():
        raise EvaluationError(f"{path} is missing: {INCOMPLETE_FIX}")
    size = path.stat().st_size
    with open(path, "rb") as handle:
        prefix = handle.read(8)
        length = int.from_bytes(prefix, "little") if len(prefix) == 8 else -1
        if not 0 < length <= size - 8:
            raise EvaluationError(f"{path} is truncated or damaged ({size} bytes, no readable header): {INCOMPLETE_FIX}")
        try:
            header = json.loads(handle.read(length))
            ends = [int(entry["data_offsets"][1]) for key, entry in header.items() if key != "__metadata__"]
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError, KeyError, IndexError, TypeError, ValueError):
            raise EvaluationError(f"{path} is truncated or damaged (its header does not parse): {INCOMPLETE_FIX}") from None
    expected = 8 + length + max(ends, default=0)
    if expected != size:
        raise EvaluationError(
            f"{path} is truncated or damaged ({size} bytes, its header describes {expected}): {INCOMPLETE_FIX}"
        )


@functools.cache
def register_policy_types() -> None:
    """Make every policy type a config.json may name known to LeRobot's factory, as lerobot-eval does: LeRobot's
    own, MOSAIC, and the installed `lerobot_policy_*` plugins."""
    import logging

    import lerobot.policies  # noqa: F401  (registers LeRobot's config classes)
    from lerobot.utils.import_utils import register_third_party_plugins

    import mosaic_policy  # noqa: F401

    level = logging.getLogger().level
    logging.getLogger().setLevel(logging.CRITICAL)  # a broken unrelated plugin must not print a traceback here
    try:
        register_third_party_plugins()
    finally:
        logging.getLogger().setLevel(level)


def policy_class(checkpoint: Path, policy_type: str) -> type:
    """The LeRobot policy class of ``policy_type`` (its modeling module is imported, its weights are not read)."""
    from lerobot.policies.factory import get_policy_class

    register_policy_types()
    try:
        return get_policy_class(policy_type)
    except ValueError:
        raise EvaluationError(
            f"{str(checkpoint)!r} holds a {policy_type!r} policy that LeRobot does not know: install the package "
            "that registers it (a lerobot_policy_* plugin)"
        ) from None
    except ImportError as error:
        raise EvaluationError(
            f"the {policy_type!r} policy cannot be imported ({error}): install its dependencies"
        ) from None


def policy_config(checkpoint: Path, options: dict[str, Any]):
    """The checkpoint's LeRobot config with ``options`` (inference options such as ``n_action_steps``) set, checked
    by the config class itself, as ``lerobot-eval --policy.X=V`` does."""
    import dataclasses

    from lerobot.configs.policies import PreTrainedConfig

    register_policy_types()
    config = PreTrainedConfig.from_pretrained(checkpoint)
    if not options:
        return config
    fields = {f.name for f in dataclasses.fields(config) if f.init}
    for name in options:
        if name not in fields:
            raise EvaluationError(
                f"--policy.{name} is not an option of {config.type!r} policies ({checkpoint}): leave it out for them"
            )
    try:
        return dataclasses.replace(config, **options)
    except (ValueError, TypeError, NotImplementedError) as error:  # LeRobot's ACT refuses with NotImplementedError
        raise EvaluationError(f"{checkpoint}: {' '.join(str(error).split())}") from None


def takes_demo(cls: type) -> bool:
    """Whether a policy class is conditioned on a demonstration (MOSAIC's `set_demo`)."""
    return callable(getattr(cls, "set_demo", None))


def checkpoint_image_hw(path: Path, config: dict[str, Any]) -> tuple[int, int]:
    """(H, W) of the camera a checkpoint at ``path`` was trained on, after checking that its inputs and action are
    what the MOSAIC environments provide (the scene renders at the checkpoint's camera size, so any size fits)."""
    features = config.get("input_features") or {}
    unknown = sorted(set(features) - {CAMERA_KEY, STATE_KEY})
    if unknown:
        raise EvaluationError(
            f"{path} expects input {', '.join(unknown)} but the MOSAIC tasks provide only {PROVIDED}: "
            "train the policy on a mosaic-data dataset"
        )
    camera = features.get(CAMERA_KEY)
    if camera is None:
        raise EvaluationError(
            f"{path} has no {CAMERA_KEY} input; mosaic-eval renders {CAMERA_KEY}: train the policy on a mosaic-data dataset"
        )
    if len(camera["shape"]) != 3 or camera["shape"][0] != 3:
        raise EvaluationError(f"{path} expects {CAMERA_KEY} of shape {tuple(camera['shape'])}; the tasks render 3xHxW RGB")
    state = features.get(STATE_KEY)
    if state is not None and tuple(state["shape"]) != (STATE_DIM,):
        raise EvaluationError(
            f"{path} expects {STATE_KEY} of shape {tuple(state['shape'])} but the MOSAIC tasks give ({STATE_DIM},): "
            "train the policy on a mosaic-data dataset"
        )
    action = (config.get("output_features") or {}).get(ACTION_KEY)
    if action is None or tuple(action["shape"]) != (ACTION_DIM,):
        shape = tuple(action["shape"]) if action else None
        raise EvaluationError(
            f"{path} outputs action of shape {shape}; the MOSAIC tasks take ({ACTION_DIM},) end-effector targets"
        )
    return int(camera["shape"][-2]), int(camera["shape"][-1])


# ---------------------------------------------------------------------------------------------- agents


def workspace_action_stats() -> dict[str, dict[str, torch.Tensor]]:
    """Action min/max = the environment's action box, so that an untrained head's [-1, 1] spans the workspace."""
    from mosaic_data.envs import ACTION_HIGH, ACTION_LOW

    return {ACTION_KEY: {"min": torch.from_numpy(ACTION_LOW.copy()), "max": torch.from_numpy(ACTION_HIGH.copy())}}


def policy_agent_spec(path: str, options: dict[str, Any], record: bool = False) -> tuple[AgentSpec, dict[str, Any]]:
    """The agent of the checkpoint at ``path`` with the inference ``options`` (``--policy.NAME``), and its config.

    The checks need only config.json and run first (an EvaluationError names the fix); the weights file is checked
    next, and a bad option value is reported here, before any worker starts."""
    checkpoint = resolve_checkpoint(path)
    config = read_config(checkpoint)
    image_hw = checkpoint_image_hw(checkpoint, config)
    with_demo = takes_demo(policy_class(checkpoint, config["type"]))
    check_checkpoint_files(checkpoint)
    if options:
        policy_config(checkpoint, options)
    spec = AgentSpec(
        "policy", str(path), str(checkpoint), image_hw, record, takes_demo=with_demo, policy_options=tuple(options.items())
    )
    return spec, config


def untrained_mosaic(height: int, width: int, **options: Any) -> tuple[Any, Any, Any]:
    """(policy, preprocessor, postprocessor): MOSAIC at initialisation, the same weights in every process (seed 0),
    with an action range that is the workspace box. The paper's "No Training" row; the untrained checkpoints that
    benchmarks and tests save. ``options`` are MosaicConfig fields (sizes)."""
    from mosaic_policy import MosaicConfig, make_mosaic_pre_post_processors
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    config = MosaicConfig(device="cpu", **policy_features(height, width), push_to_hub=False, **options)
    torch.manual_seed(0)
    policy = MosaicPolicy(config)
    stats = workspace_action_stats() | {STATE_KEY: {"mean": torch.zeros(STATE_DIM), "std": torch.ones(STATE_DIM)}}
    preprocessor, postprocessor = make_mosaic_pre_post_processors(config, dataset_stats=stats)
    return policy, preprocessor, postprocessor


class PolicyAgent:
    """A LeRobot policy with its pre/post-processors (a checkpoint of any type, or MOSAIC untrained for the sanity row)."""

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

        path = resolve_checkpoint(spec.path)
        config = policy_config(path, dict(spec.policy_options))
        config.device = "cpu" if not torch.cuda.is_available() else config.device
        if getattr(config, "pretrained_backbone_weights", None):
            config.pretrained_backbone_weights = None  # the checkpoint holds the trained backbone: no ImageNet download
        with contextlib.redirect_stdout(io.StringIO()):  # LeRobot prints "Loading weights from local directory" through our bar
            policy = policy_class(path, config.type).from_pretrained(path, config=config)
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
        return cls(spec, *untrained_mosaic(*spec.image_hw))

    @property
    def attention_hw(self) -> tuple[int, int] | None:
        """(h, w) of the token grid the recorded attention covers; None for a policy without attention maps."""
        if not self.spec.record_attention or not hasattr(self.policy, "predict_with_attention"):
            return None
        return tuple(self.policy.model.feature_shape[1:])

    def start_episode(self, env: MosaicGymEnv, demo: Demonstration | None) -> None:
        self.policy.reset()  # also empties an action-chunk queue (ACT) left from the last episode
        if not self.spec.takes_demo:
            return
        if demo is None:
            raise EvaluationError("a demonstration-conditioned policy needs a demonstration for every episode")
        self.policy.set_demo(demo.frames)

    @torch.no_grad()
    def act(self, observation: dict[str, Any], env: MosaicGymEnv) -> AgentStep:
        from lerobot.envs.utils import preprocess_observation

        batch = preprocess_observation(observation)
        batch["task"] = [env.task_description]
        batch = self.preprocessor(batch)
        if self.attention_hw is not None:
            action, weights = self.policy.predict_with_attention(batch)
            attention = [layer[0, :, 0].float().cpu().numpy() for layer in weights]
        else:
            action, attention = self.policy.select_action(batch), None
        action = self.postprocessor(action)
        return AgentStep(action=action[0].cpu().numpy().astype(np.float64), attention=attention)


class ExpertAgent:
    """The task's scripted expert for the agent's robot, acting through the same loop (the sanity row).

    With ``spec.expert_variation`` it pursues that variation whatever the episode's: an agent that ignores the
    demonstration, which the confusion matrix must show as one column (tested)."""

    def __init__(self, spec: AgentSpec) -> None:
        self.spec = spec
        self._expert = None

    def start_episode(self, env: MosaicGymEnv, demo: Demonstration | None) -> None:
        from mosaic_data.experts import make_expert

        self._expert = make_expert(env.task_env, variation=self.spec.expert_variation)

    def act(self, observation: dict[str, Any], env: MosaicGymEnv) -> AgentStep:
        action = np.asarray(self._expert.act(), dtype=np.float64)
        return AgentStep(action=action, phase=self._expert.acting_phase)


def build_agent(spec: AgentSpec) -> Agent:
    return ExpertAgent(spec) if spec.kind == "expert" else PolicyAgent.from_spec(spec)
