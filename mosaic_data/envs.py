"""gymnasium front end of the task suite: ``gymnasium.make("mosaic/Door-v0", variation=1, robot="panda")``.

Observations follow LeRobot's gym-environment convention so that its ``preprocess_observation`` works as is:
``{"pixels": {"agentview": uint8 (H, W, 3)}, "agent_pos": float32 (10,)}``. ``info["is_success"]`` is set on
every step, as LeRobot's evaluation expects. The episode terminates on success and is truncated at the task's
horizon.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from mosaic_data.tasks import TASKS, make_task_env
from mosaic_data.tasks.base import ACTION_DIM, IMAGE_HEIGHT, IMAGE_WIDTH, STATE_DIM, MosaicTaskEnv

GYM_NAMES: dict[str, str] = {
    "door": "Door",
    "drawer": "Drawer",
    "press_button": "PressButton",
    "stack_block": "StackBlock",
    "basketball": "Basketball",
    "nut_assembly": "NutAssembly",
    "pick_place": "PickPlace",
}
"""Task key -> gymnasium environment name (``mosaic/<Name>-v0``)."""

WORKSPACE_LOW = np.array([-0.6, -0.6, 0.75])
WORKSPACE_HIGH = np.array([0.5, 0.6, 1.5])
"""Bounds (m) of the action's target position, a box around the table that both robots can reach."""
ACTION_LOW = np.concatenate([WORKSPACE_LOW, [-np.pi] * 3, [-1.0]]).astype(np.float32)
ACTION_HIGH = np.concatenate([WORKSPACE_HIGH, [np.pi] * 3, [1.0]]).astype(np.float32)
"""The action box: target position in the workspace, rotation vector from gripper-down (see
:mod:`mosaic_data.tasks.base`) in [-pi, pi] per component, gripper in [-1, 1]."""


def gym_id(task: str) -> str:
    return f"mosaic/{GYM_NAMES[task]}-v0"


class MosaicGymEnv(gym.Env):
    """One task variation for one robot as a gymnasium environment (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task: str,
        variation: int = 0,
        robot: str = "panda",
        render_mode: str | None = "rgb_array",
        image_height: int = IMAGE_HEIGHT,
        image_width: int = IMAGE_WIDTH,
        observe_image: bool = True,
        horizon: int | None = None,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"unsupported render_mode {render_mode!r}: use 'rgb_array' or None")
        self.task_env: MosaicTaskEnv = make_task_env(
            task, variation, robot, image_height=image_height, image_width=image_width, horizon=horizon
        )
        self.task = task
        self.render_mode = render_mode
        self.observe_image = observe_image
        self.horizon = self.task_env.horizon
        self._max_episode_steps = self.horizon  # what LeRobot's evaluation loop reads as the episode length
        self._frame: np.ndarray | None = None  # the current state's camera frame, once rendered
        observation = {"agent_pos": spaces.Box(-np.inf, np.inf, (STATE_DIM,), np.float32)}
        if observe_image:
            observation["pixels"] = spaces.Dict(
                {"agentview": spaces.Box(0, 255, (image_height, image_width, 3), np.uint8)}
            )
        self.observation_space = spaces.Dict(observation)
        self.action_space = spaces.Box(low=ACTION_LOW, high=ACTION_HIGH, dtype=np.float32)
        self._steps = 0

    # ------------------------------------------------------------------ gymnasium API
    @property
    def variation(self) -> int:
        return self.task_env.variation_index

    @property
    def task_description(self) -> str:
        """The variation's description, also the LeRobot task string of its episodes."""
        return self.task_env.variation.description

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        instance_seed = seed if seed is not None else int(self.np_random.integers(0, 2**31 - 1))
        self.task_env.reset_to_seed(instance_seed)
        self._steps = 0
        return self._observation(), self._info(success=False)

    def step(self, action):
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        if action.shape != (ACTION_DIM,):
            raise ValueError(
                f"action must have {ACTION_DIM} values [x, y, z, rx, ry, rz, gripper], got shape {action.shape}"
            )
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action contains NaN or inf: {action}")
        self.task_env.step(action)
        self._steps += 1
        success = self.task_env.check_success()
        truncated = self._steps >= self.horizon and not success
        return self._observation(), float(success), success, truncated, self._info(success)

    def render(self) -> np.ndarray | None:
        """The camera frame of the current state (the observation's own frame when it has one: no second render)."""
        if self.render_mode is None:
            return None
        if self._frame is None:
            self._frame = self.task_env.render_agentview()
        return self._frame

    def close(self) -> None:
        self.task_env.close()

    # ------------------------------------------------------------------ helpers
    def _observation(self) -> dict[str, Any]:
        observation: dict[str, Any] = {"agent_pos": self.task_env.robot_state()}
        self._frame = self.task_env.render_agentview() if self.observe_image else None
        if self._frame is not None:
            observation["pixels"] = {"agentview": self._frame}
        return observation

    def _info(self, success: bool) -> dict[str, Any]:
        return {
            "is_success": bool(success),
            "task": self.task_description,
            "variation": self.variation,
            "seed": self.task_env.instance_seed,
        }


def register_envs() -> None:
    """Register ``mosaic/<Name>-v0`` for every task of the suite (idempotent)."""
    for task in TASKS:
        env_id = gym_id(task)
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point="mosaic_data.envs:MosaicGymEnv", kwargs={"task": task})
