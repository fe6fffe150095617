"""Shared robosuite base for every MOSAIC task.

A task is one robosuite ``ManipulationEnv`` subclass that builds a fixed scene (fixtures and objects), whose
*variation* (which door, which drawer, which button, ...) is chosen at construction, and whose *instance*
(the exact layout and the robot's initial joint noise) is drawn from the ``seed`` given to :meth:`reset_to_seed`.

Conventions shared by every task (the same for the Panda agent and the Sawyer demonstrator):

* World frame: robosuite's. Origin on the floor under the table centre, +x away from the robot, +y to the
  robot's left, +z up. Lengths in metres, angles in radians.
* Action (7,): absolute world-frame end-effector target ``[x, y, z, rx, ry, rz, gripper]``: position of the
  gripper's grip site; orientation as the rotation vector (rad) of the world-frame turn that takes the
  gripper-down reference ``GRIPPER_DOWN`` to the target orientation (``target = exp(r) * GRIPPER_DOWN``);
  gripper ``-1`` open ... ``+1`` closed. Every task grasps from above, so ``r`` stays far from the axis-angle
  singularity at pi (a plain world axis-angle of a top-down grasp has magnitude ~pi and flips sign as the hand
  turns a few degrees: a learned policy would average +pi and -pi); a turn of the hand by ``yaw`` about the
  vertical is ``r = (0, 0, yaw)``. Converted to robosuite's absolute axis-angle in :meth:`MosaicTaskEnv.step`
  and executed by its OSC_POSE controller (``input_type="absolute"``, ``input_ref_frame="world"``) at 20 Hz.
* State (10,): grip-site position (3), orientation as the first two columns of its rotation matrix (6,
  continuous, unlike axis-angle near a top-down grasp), gripper opening in ``[0, 1]`` (1 = fully open).
* Camera ``agentview``: 100 x 180 (H x W) RGB, right side up. Rendered only when asked for, because on a
  CPU the renderer costs most of a step. ``fast_render`` (default) turns off shadows, reflections and the
  skybox, and ``visual_face_budget`` (default 800, None = robosuite's meshes) renders the robots' detailed
  visual meshes from simplified copies: faster frames (README), the same physics (``render_meshes``). The rendering
  half of the environment (camera, render buffers, frames drawn after the fact) is :mod:`.rendering`.
"""

from __future__ import annotations

import copy
import logging
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from mosaic_data.tasks.robosuite_log import quiet_robosuite_import

quiet_robosuite_import()  # before the first robosuite import: its import-time warnings do not apply here

from robosuite.controllers import load_composite_controller_config  # noqa: E402
from robosuite.environments.manipulation.manipulation_env import ManipulationEnv  # noqa: E402
from robosuite.models.arenas import TableArena  # noqa: E402
from robosuite.models.tasks import ManipulationTask  # noqa: E402
from robosuite.utils.log_utils import ROBOSUITE_DEFAULT_LOGGER  # noqa: E402

from mosaic_data.tasks.render_meshes import VISUAL_FACE_BUDGET  # noqa: E402
from mosaic_data.tasks.rendering import AgentviewRendering, look_at_quat_wxyz  # noqa: E402
from mosaic_data.tasks.spec import (  # noqa: E402, F401  (the suite's conventions, re-exported here)
    ACTION_DIM,
    CONTROL_FREQ_HZ,
    GRIPPER_CLOSED,
    GRIPPER_OPEN,
    IMAGE_HEIGHT,
    IMAGE_WIDTH,
    ROBOTS,
    STATE_DIM,
    Variation,
    check_variation,
    validate_robot,
)

# robosuite logs every controller load at INFO; keep warnings and errors only.
ROBOSUITE_DEFAULT_LOGGER.setLevel(logging.WARNING)

OSC_STIFFNESS = 600.0


GRIPPER_DOWN = Rotation.from_matrix(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]))
"""Gripper pointing straight down, fingers closing along the world y axis: the reference of the action's rotation."""


def action_rotation(rotation: Rotation) -> np.ndarray:
    """Rotation vector (3,) of an orientation in the action's chart (the turn from ``GRIPPER_DOWN``, world frame)."""
    return (rotation * GRIPPER_DOWN.inv()).as_rotvec()


def rotation_from_action(rotation_vector: Sequence[float]) -> Rotation:
    """The orientation an action's rotation vector stands for (inverse of :func:`action_rotation`)."""
    return Rotation.from_rotvec(np.asarray(rotation_vector, dtype=float)) * GRIPPER_DOWN


def rotation_to_state(rotation: Rotation) -> np.ndarray:
    """First two columns of the rotation matrix (6 numbers), a continuous orientation encoding."""
    return rotation.as_matrix()[:, :2].T.reshape(-1)


class MosaicTaskEnv(AgentviewRendering, ManipulationEnv):
    """Base class of the seven MOSAIC tasks (see the module docstring for frames, units and layouts).

    Subclasses set ``task_name``, ``variations`` and ``horizon_steps`` and implement the same named steps
    in every file: ``_load_task_objects`` (fixtures and objects), ``_setup_task_references`` (ids),
    ``_place_instance`` (layout from the instance's random generator) and ``_goal_reached``
    (the variation-specific success test). The agentview camera's rendering comes from
    :class:`~mosaic_data.tasks.rendering.AgentviewRendering`.
    """

    task_name: ClassVar[str]
    variations: ClassVar[tuple[Variation, ...]]
    horizon_steps: ClassVar[int] = 200
    table_full_size: ClassVar[tuple[float, float, float]] = (0.8, 1.0, 0.05)
    table_offset: ClassVar[np.ndarray] = np.array((0.0, 0.0, 0.8))
    robot_joint_noise_rad: ClassVar[float] = 0.02
    # Camera looking at the workspace from behind the fixtures, slightly to the side, like the paper's.
    camera_pos: ClassVar[tuple[float, float, float]] = (0.5, 0.0, 1.55)
    camera_target: ClassVar[tuple[float, float, float]] = (-0.3, 0.0, 0.85)
    camera_fovy_deg: ClassVar[float] = 45.0

    def __init__(
        self,
        variation: int = 0,
        robot: str = "panda",
        image_height: int = IMAGE_HEIGHT,
        image_width: int = IMAGE_WIDTH,
        horizon: int | None = None,
        fast_render: bool = True,
        visual_face_budget: int | None = VISUAL_FACE_BUDGET,
    ) -> None:
        self.variation_index = self.validate_variation(variation)
        self.variation = self.variations[self.variation_index]
        self.robot_key = validate_robot(robot)
        self.image_height = int(image_height)
        self.image_width = int(image_width)
        self.fast_render = fast_render
        self.visual_face_budget = visual_face_budget
        self.instance_seed: int | None = None
        self._instance_rng = np.random.default_rng(0)
        self._robot_rng = np.random.default_rng(0)
        robot_name = ROBOTS[self.robot_key]
        super().__init__(
            robots=robot_name,
            controller_configs=absolute_world_pose_controller(robot_name),
            initialization_noise=None,
            use_camera_obs=False,
            has_renderer=False,
            has_offscreen_renderer=True,
            render_camera="agentview",
            control_freq=CONTROL_FREQ_HZ,
            horizon=horizon or self.horizon_steps,
            ignore_done=True,
            hard_reset=False,
            camera_names="agentview",
            camera_heights=self.image_height,
            camera_widths=self.image_width,
        )

    # ------------------------------------------------------------------ validation
    @classmethod
    def validate_variation(cls, variation: int) -> int:
        return check_variation(cls.task_name, len(cls.variations), variation)

    def set_variation(self, variation: int) -> None:
        """Switch to another variation of the same scene; it takes effect at the next reset.

        Every task builds all its fixtures and objects whatever the variation, so one environment can serve
        all variations (much cheaper than building one per variation).
        """
        self.variation_index = self.validate_variation(variation)
        self.variation = self.variations[self.variation_index]

    # ------------------------------------------------------------------ acting
    def step(self, action):
        """One 20 Hz control step with an action in the suite's convention (module docstring).

        robosuite's OSC takes an absolute world axis-angle; the action's rotation is relative to ``GRIPPER_DOWN``.
        """
        action = np.array(action, dtype=float)
        action[3:6] = rotation_from_action(action[3:6]).as_rotvec()
        return super().step(action)

    # ------------------------------------------------------------------ model
    def _load_model(self) -> None:
        super()._load_model()
        robot_model = self.robots[0].robot_model
        robot_model.set_base_xpos(robot_model.base_xpos_offset["table"](self.table_full_size[0]))
        arena = TableArena(table_full_size=self.table_full_size, table_offset=self.table_offset)
        arena.set_origin([0, 0, 0])
        arena.set_camera(
            camera_name="agentview",
            pos=list(self.camera_pos),
            quat=look_at_quat_wxyz(np.array(self.camera_pos), np.array(self.camera_target)),
            camera_attribs={"fovy": str(self.camera_fovy_deg)},
        )
        self.model = ManipulationTask(
            mujoco_arena=arena,
            mujoco_robots=[robot.robot_model for robot in self.robots],
            mujoco_objects=self._load_task_objects(),
        )
        self._exclude_self_contacts()

    # robosuite 1.5.1's Sawyer rests its first link on its arm base; MuJoCo does not filter that contact
    # (the base is welded to the world), so the base joint j0 is locked and the arm can only reach sideways
    # with its other joints, leaving centimetres of tracking error.
    _EXCLUDED_CONTACTS: ClassVar[dict[str, tuple[tuple[str, str], ...]]] = {
        "sawyer": (("robot0_right_arm_base_link", "robot0_right_l0"),),
    }

    def _exclude_self_contacts(self) -> None:
        body_names = {body.get("name") for body in self.model.worldbody.iter("body")}
        for first, second in self._EXCLUDED_CONTACTS.get(self.robot_key, ()):
            if first in body_names and second in body_names:
                self.model.contact.append(ET.Element("exclude", body1=first, body2=second))

    def _load_task_objects(self) -> list:
        raise NotImplementedError

    def _setup_references(self) -> None:
        super()._setup_references()
        self._setup_task_references()

    def _setup_task_references(self) -> None:
        """Look up the ids of the bodies, joints and sites the task reads."""

    # ------------------------------------------------------------------ instances
    def reset_to_seed(self, seed: int | None) -> None:
        """Reset the scene to the instance that ``seed`` determines (the same for both robots)."""
        self.instance_seed = None if seed is None else int(seed)
        scene_seq, robot_seq = np.random.SeedSequence(self.instance_seed).spawn(2)
        self._instance_rng = np.random.default_rng(scene_seq)
        self._robot_rng = np.random.default_rng(robot_seq)
        self.reset()

    def _reset_internal(self) -> None:
        super()._reset_internal()
        robot = self.robots[0]
        joint_ids = robot._ref_joint_pos_indexes
        noise = self._robot_rng.uniform(-1.0, 1.0, len(joint_ids)) * self.robot_joint_noise_rad
        self.sim.data.qpos[joint_ids] = np.array(robot.init_qpos) + noise
        self.sim.data.qvel[:] = 0.0
        self._place_instance(self._instance_rng)
        self.sim.forward()
        robot.composite_controller.update_state()
        robot.composite_controller.reset()
        if self.fast_render:
            self._configure_fast_render()

    def _place_instance(self, rng: np.random.Generator) -> None:
        """Place fixtures/objects and set their joints for this instance."""
        raise NotImplementedError

    def set_fixture_pose(self, body_id: int, pos: Sequence[float], yaw_rad: float = 0.0) -> None:
        """Move a jointless fixture body (model-level pose, valid until the next instance)."""
        self.sim.model.body_pos[body_id] = np.asarray(pos, dtype=float)
        self.sim.model.body_quat[body_id] = Rotation.from_euler("z", yaw_rad).as_quat(scalar_first=True)

    # ------------------------------------------------------------------ success
    def check_success(self, variation: int | None = None) -> bool:
        """True when the goal of ``variation`` (default: this env's own) is reached in the current state."""
        chosen = self.variation if variation is None else self.variations[self.validate_variation(variation)]
        return bool(self._goal_reached(chosen))

    def _goal_reached(self, variation: Variation) -> bool:
        raise NotImplementedError

    def _check_success(self) -> bool:
        return self.check_success()

    def reward(self, action=None) -> float:
        """Sparse reward: 1 when the variation's goal is reached."""
        return float(self.check_success())

    # ------------------------------------------------------------------ observations
    @property
    def robot(self):
        return self.robots[0]

    @property
    def eef_pos(self) -> np.ndarray:
        return np.array(self.sim.data.site_xpos[self.robot.eef_site_id["right"]])

    @property
    def eef_rotation(self) -> Rotation:
        return Rotation.from_matrix(self.sim.data.site_xmat[self.robot.eef_site_id["right"]].reshape(3, 3))

    @property
    def gripper_opening(self) -> float:
        """Gripper opening in [0, 1], 1 fully open, from the finger joints and their ranges.

        robosuite's grippers start fully open, so the range end nearest ``init_qpos`` is "open".
        """
        gripper = self.robot.gripper["right"]
        qpos_ids = self.robot._ref_gripper_joint_pos_indexes["right"]
        opening = []
        for qpos_id, joint_name, open_guess in zip(qpos_ids, gripper.joints, gripper.init_qpos):
            lo, hi = self.sim.model.jnt_range[self.sim.model.joint_name2id(joint_name)]
            open_q, closed_q = (lo, hi) if abs(open_guess - lo) < abs(open_guess - hi) else (hi, lo)
            opening.append((self.sim.data.qpos[qpos_id] - closed_q) / (open_q - closed_q))
        return float(np.clip(np.mean(opening), 0.0, 1.0))

    def robot_state(self) -> np.ndarray:
        """State vector (10,): position, rotation 6D, gripper opening (see module docstring)."""
        return np.concatenate(
            [self.eef_pos, rotation_to_state(self.eef_rotation), [self.gripper_opening]]
        ).astype(np.float32)

    # ------------------------------------------------------------------ helpers for subclasses
    def body_id(self, name: str) -> int:
        return self.sim.model.body_name2id(name)

    def joint_qpos_address(self, name: str) -> int:
        return int(self.sim.model.jnt_qposadr[self.sim.model.joint_name2id(name)])

    def joint_value(self, name: str) -> float:
        return float(self.sim.data.qpos[self.joint_qpos_address(name)])

    def set_joint_value(self, name: str, value: float) -> None:
        self.sim.data.qpos[self.joint_qpos_address(name)] = value


def absolute_world_pose_controller(robot_name: str) -> dict:
    """robosuite's default controller for the robot with its arm in absolute world-frame OSC_POSE mode."""
    config = copy.deepcopy(load_composite_controller_config(robot=robot_name))
    arm = config["body_parts"]["right"] if "right" in config["body_parts"] else config["body_parts"]["arms"]["right"]
    # Stiffer than robosuite's default (kp 150): with absolute targets moved in small steps,
    # the default leaves the Sawyer lagging several centimetres behind its target.
    arm.update({"type": "OSC_POSE", "input_type": "absolute", "input_ref_frame": "world", "kp": OSC_STIFFNESS})
    return config
