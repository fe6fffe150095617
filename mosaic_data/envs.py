"""gymnasium front end of the task suite: ``gymnasium.make("mosaic/Door-v0", variation=1, robot="panda")``.

Observations follow LeRobot's gym-environment convention so that its ``preprocess_observation`` works as is:
``{"pixels": {"agentview": uint8 (H, W, 3)}, "agent_pos": float32 (10,)}``. ``info["is_success"]`` is set on
every step, as LeRobot's evaluation expects. The episode terminates on success; the registered environments
carry the task's horizon as ``max_episode_steps``, so gymnasium's ``TimeLimit`` truncates them
(``gymnasium.make(..., max_episode_steps=N)`` changes it). ``reset(options={"variation": k})`` switches the
variation in the same scene; ``info["variation"]`` and ``info["task"]`` say which one is running.

The simulator, and with it the GL context, is built on first use, not in the constructor: gymnasium's async
vector env makes one environment in the parent for its spaces and then forks its workers, and a child forked
after its parent made a GL context hangs in its first render. So
``gymnasium.make_vec(id, num_envs=n, vectorization_mode="async")`` works with gymnasium's defaults.
"""

from __future__ import annotations

import difflib
import os
import sys
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from mosaic_data.tasks import TASK_NAMES  # task keys only: registering must not load the simulator
from mosaic_data.tasks import CLASS_NAMES, make_task_env
from mosaic_data.tasks.spec import ACTION_DIM, IMAGE_HEIGHT, IMAGE_WIDTH, STATE_DIM, get_task_spec, validate_robot

if TYPE_CHECKING:
    import mujoco

    from mosaic_data.tasks.base import MosaicTaskEnv

GYM_NAMES: dict[str, str] = CLASS_NAMES
"""Task key -> gymnasium environment name (``mosaic/<Name>-v0``)."""

WORKSPACE_LOW = np.array([-0.6, -0.6, 0.75])
WORKSPACE_HIGH = np.array([0.5, 0.6, 1.5])
"""Bounds (m) of the action's target position, a box around the table that both robots can reach."""
ACTION_LOW = np.concatenate([WORKSPACE_LOW, [-np.pi] * 3, [-1.0]]).astype(np.float32)
ACTION_HIGH = np.concatenate([WORKSPACE_HIGH, [np.pi] * 3, [1.0]]).astype(np.float32)
"""The action box: target position in the workspace, rotation vector from gripper-down (see
:mod:`mosaic_data.tasks.base`) in [-pi, pi] per component, gripper in [-1, 1]."""

GRIP_SITE_REACH: dict[str, tuple[tuple[float, float, float], float]] = {
    "panda": ((-0.56, 0.0, 1.245), 1.09),
    "sawyer": ((-0.56, 0.0, 0.992), 1.46),
}
"""Robot -> (world position of its first joint's pivot, reach in m rounded up to the cm): the grip site stays in
this ball whatever the joint angles, because the links after the pivot cannot add up to more than their lengths.
Derived from the compiled scene by :func:`grip_site_reach` (a test checks the numbers against it); written out
so that making an environment needs no simulator."""


def gym_id(task: str) -> str:
    return f"mosaic/{GYM_NAMES[task]}-v0"


def agent_pos_bounds(robot: str) -> tuple[np.ndarray, np.ndarray]:
    """Finite (low, high) of the state vector (10,) of ``robot``: the grip site inside the box around its reach
    ball, rotation-matrix entries in [-1, 1], gripper opening in [0, 1]."""
    centre, reach = GRIP_SITE_REACH[validate_robot(robot)]
    low = np.concatenate([np.asarray(centre) - reach, -np.ones(6), [0.0]]).astype(np.float32)
    high = np.concatenate([np.asarray(centre) + reach, np.ones(6), [1.0]]).astype(np.float32)
    return low, high


def grip_site_reach(model: mujoco.MjModel, site_id: int) -> tuple[np.ndarray, float]:
    """(pivot, reach) of a site at the end of a hinge chain: the world position of the first jointed body's origin
    (fixed, as nothing above it moves) and the sum of the offsets from there to the site, an upper bound of their
    distance for any joint angles (triangle inequality). Raises if the chain has joints this bound does not cover."""
    import mujoco

    chain = []  # bodies from the site's body up to (not including) the world body
    body = int(model.site_bodyid[site_id])
    while body != 0:
        chain.append(body)
        body = int(model.body_parentid[body])
    jointed = [body for body in chain if model.body_jntnum[body] > 0]
    if not jointed:
        raise ValueError("the site is fixed to the world: no reach to bound")
    for body in jointed:
        for joint in range(model.body_jntadr[body], model.body_jntadr[body] + model.body_jntnum[body]):
            if model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_HINGE or np.any(model.jnt_pos[joint]):
                raise ValueError(f"joint {model.joint(joint).name!r} is not a hinge at its body's origin")
    first = jointed[-1]
    reach = float(np.linalg.norm(model.site_pos[site_id]))
    reach += sum(float(np.linalg.norm(model.body_pos[body])) for body in chain[: chain.index(first)])
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    return data.xpos[first].copy(), reach


_GL_INHERITED = False
"""True in a process forked after its parent had initialised robosuite's EGL display (see :func:`_note_fork`)."""


def _note_fork() -> None:
    """Runs in every forked child: remember whether the parent had already initialised robosuite's EGL display.

    robosuite keeps that display in a module global, so the child reuses a display whose state did not survive
    the fork, and its first scene hangs forever (tested); building a scene there fails fast instead."""
    global _GL_INHERITED
    egl = sys.modules.get("robosuite.renderers.context.egl_context")
    _GL_INHERITED = _GL_INHERITED or getattr(egl, "EGL_DISPLAY", None) is not None


os.register_at_fork(after_in_child=_note_fork)


class MosaicGymEnv(gym.Env):
    """One task variation for one robot as a gymnasium environment (see the module docstring).

    ``horizon`` is the episode length read by code that runs episodes itself (``mosaic-eval``); registered
    environments get theirs from ``max_episode_steps``.
    """

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
        self._spec = get_task_spec(task)
        self.task = task
        self._variation = self._spec.validate_variation(variation)
        self.robot = validate_robot(robot)
        for name, size in (("image_height", image_height), ("image_width", image_width)):
            if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 1:
                raise ValueError(f"{name} must be a positive integer (pixels), got {size!r}")
        bad_horizon = isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1
        if horizon is not None and bad_horizon:
            raise ValueError(f"horizon must be a positive integer (control steps) or None, got {horizon!r}")
        self.image_height, self.image_width = int(image_height), int(image_width)
        self.render_mode = render_mode
        self.observe_image = observe_image
        self.horizon = int(horizon) if horizon is not None else self._spec.horizon_steps
        self._task_env: MosaicTaskEnv | None = None  # built on first use (module docstring)
        self._frame: np.ndarray | None = None  # the current state's camera frame, once rendered
        low, high = agent_pos_bounds(robot)
        observation = {"agent_pos": spaces.Box(low, high, (STATE_DIM,), np.float32)}
        if observe_image:
            observation["pixels"] = spaces.Dict(
                {"agentview": spaces.Box(0, 255, (self.image_height, self.image_width, 3), np.uint8)}
            )
        self.observation_space = spaces.Dict(observation)
        self.action_space = spaces.Box(low=ACTION_LOW, high=ACTION_HIGH, dtype=np.float32)

    # ------------------------------------------------------------------ the simulator, built on first use
    @property
    def task_env(self) -> MosaicTaskEnv:
        """The robosuite scene; the first access builds it (seconds) in the process that uses it."""
        if self._task_env is None:
            if _GL_INHERITED:
                raise RuntimeError(
                    "this process was forked after its parent had rendered a mosaic scene, and EGL hangs in such a "
                    "child: create the envs in fresh processes, e.g. gymnasium.make_vec(..., vectorization_mode="
                    "'async', vector_kwargs={'context': 'spawn'}), or before the parent renders"
                )
            self._task_env = make_task_env(
                self.task, self._variation, self.robot,
                image_height=self.image_height, image_width=self.image_width, horizon=self.horizon,
            )
        return self._task_env

    # ------------------------------------------------------------------ gymnasium API
    @property
    def variation(self) -> int:
        return self._variation

    @property
    def task_description(self) -> str:
        """The variation's description, also the LeRobot task string of its episodes."""
        return self._spec.variations[self._variation].description

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """A new instance (``seed`` fixes it); ``options={"variation": k}`` switches to variation k from now on."""
        variation = self.reset_variation(options)
        super().reset(seed=seed)
        instance_seed = seed if seed is not None else int(self.np_random.integers(0, 2**31 - 1))
        self._variation = variation
        task_env = self.task_env
        if task_env.variation_index != variation:
            task_env.set_variation(variation)
        task_env.reset_to_seed(instance_seed)
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
        success = self.task_env.check_success()
        return self._observation(), float(success), success, False, self._info(success)

    def render(self) -> np.ndarray | None:
        """The camera frame of the current state (the observation's own frame when it has one: no second render)."""
        if self.render_mode is None:
            return None
        if self._frame is None:
            self._frame = self.task_env.render_agentview()
        return self._frame

    def close(self) -> None:
        if self._task_env is not None:
            self._task_env.close()
            self._task_env = None
        self._frame = None

    def reset_variation(self, options: Mapping[str, Any] | None) -> int:
        """The variation ``reset(options=options)`` runs (a wrapper that seeds by variation asks first):
        ``options["variation"]`` if given (checked first, so that a bad one changes nothing), else the current one.
        Other keys are left alone: wrappers pass their own through ``options`` (LeRobot's evaluation sends
        ``lerobot_new_rollout``); only a near miss of ``variation`` is an error."""
        if options is None:
            return self._variation
        if not isinstance(options, Mapping):
            raise ValueError(f"reset options must be a dict such as {{'variation': 0}}, got {type(options).__name__}")
        if "variation" not in options:
            typos = difflib.get_close_matches("variation", [str(key) for key in options], n=1, cutoff=0.8)
            if typos:
                raise ValueError(f"unknown reset option {typos[0]!r}: did you mean 'variation'?")
            return self._variation
        return self._spec.validate_variation(options["variation"])

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


def make_registered_env(**kwargs: Any) -> MosaicGymEnv:
    """Entry point of ``mosaic/<Name>-v0``: the episode length of a registered env is gymnasium's
    ``max_episode_steps`` (its ``TimeLimit``), so a ``horizon`` here would be silently overruled."""
    if "horizon" in kwargs:
        raise ValueError(
            "gymnasium.make sets the episode length with max_episode_steps: "
            f"pass max_episode_steps={kwargs['horizon']!r} instead of horizon"
        )
    return MosaicGymEnv(**kwargs)


def register_envs() -> None:
    """Register ``mosaic/<Name>-v0`` for every task of the suite (idempotent), truncated at the task's horizon."""
    for task in TASK_NAMES:
        env_id = gym_id(task)
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point="mosaic_data.envs:make_registered_env",
                kwargs={"task": task},
                max_episode_steps=get_task_spec(task).horizon_steps,
            )
