"""Door: two swinging doors on the table; push or pull one of them open.

Variation ``i``: door ``i // 2`` (0 = left, blue-grey; 1 = right, copper), swing direction ``i % 2``
(0 = push it away from the robot, 1 = pull it towards the robot). Both doors are double-acting gates built
from Meta-World's door and handle meshes, hung on posts in the middle of the table (the left door is the
mirror image of the right one), with the pull handle's bar reaching past the outer free edge, where both
experts act on it.

Success: the asked door's hinge is past 0.4 rad in the asked direction.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from mosaic_data.tasks.base import MosaicTaskEnv, Variation
from mosaic_data.tasks.fixtures import FixtureBuilder
from mosaic_data.tasks.spec import DOOR_NAMES, TASK_SPECS

DOOR_COLOURS = {"left": (0.32, 0.38, 0.52, 1.0), "right": (0.62, 0.36, 0.18, 1.0)}
OPENING_PER_YAW = {"left": -1.0, "right": 1.0}
SUCCESS_ANGLE_RAD = 0.4
DOOR_SCALE = 0.6
"""Meta-World's door scaled so that two fit side by side in the Panda's workspace."""

# Geometry in Meta-World's door frame (x along the door from the hinge, -y towards the robot), unscaled.
_HANDLE_BAR_Y = -0.12
_HANDLE_BAR_RADIUS = 0.019
_HANDLE_GRIP_X = 0.42
"""Point of the handle bar, past the door's free edge (0.365), where the experts push or hook."""


class Door(MosaicTaskEnv):
    task_name: ClassVar[str] = "door"
    variations: ClassVar[tuple[Variation, ...]] = TASK_SPECS["door"].variations
    horizon_steps: ClassVar[int] = TASK_SPECS["door"].horizon_steps
    # Where each door's hinge axis stands (x, y) at the centre of the instance distribution: close to the robot
    # and shifted to its left, where the Sawyer (whose arm barely reaches past y = -0.27 here) reaches both grips
    # (y from -0.23 to +0.45) as well as the Panda.
    hinge_xy: ClassVar[dict[str, tuple[float, float]]] = {"left": (0.0, 0.17), "right": (0.0, 0.05)}
    placement_jitter_m: ClassVar[float] = 0.03
    hinge_height_m: ClassVar[float] = 0.15 * DOOR_SCALE

    def _load_task_objects(self) -> list:
        return [self._build_door(name) for name in DOOR_NAMES]

    @staticmethod
    def _build_door(name: str):
        s = DOOR_SCALE
        fixture = FixtureBuilder(f"{name}_door")
        door_mesh = fixture.mesh("door", "doorlock/door.stl", s)
        handle_mesh = fixture.mesh("door_handle", "doorlock/door_handle.stl", s)
        handle_base_mesh = fixture.mesh("handle_base", "doorlock/handle_base.stl", s)
        panel = fixture.material("panel", DOOR_COLOURS[name], texture="metal2.png")
        metal = fixture.material("metal", (0.75, 0.75, 0.75, 1.0), texture="metal1.png", shininess=0.8)
        # Fixture origin on the hinge axis at table height; inner body turns Meta-World's +y into robosuite's +x.
        fixture.open_body("frame", euler=(0, 0, -np.pi / 2))
        post_height = 0.1
        post_x = 0.03 if name == "left" else -0.03
        fixture.solid_box((0.014, 0.018, post_height), metal, pos=(post_x, 0, post_height))
        fixture.solid_box((0.05, 0.05, 0.008), metal, pos=(post_x, 0, 0.008))
        # The left door is the right one turned upside down about its normal: it opens to the robot's left.
        mirror = (0, np.pi, 0) if name == "left" else (0, 0, 0)
        fixture.open_body("door_link", pos=(0, 0, 0.15 * s), euler=mirror)
        fixture.joint("hinge", "hinge", (0, 0, 1), (-1.4, 1.4), damping=0.5, frictionloss=0.05)
        fixture.visual_mesh(door_mesh, panel, pos=(0.185 * s, 0, 0))
        fixture.visual_mesh(handle_mesh, metal, pos=(0.325 * s, -0.062 * s, 0), euler=(1.57, 0, 0))
        fixture.visual_mesh(handle_base_mesh, metal, pos=(0.325 * s, -0.006 * s, 0))
        for z in (0.07, -0.07):
            fixture.visual_box((0.013 * s, 0.013 * s, 0.045 * s), metal, pos=(0, 0, z * s))
        fixture.collision("box", (0.18 * s, 0.01 * s, 0.123 * s), pos=(0.185 * s, 0, 0), mass=2.0)
        fixture.collision("cylinder", (0.028 * s, 0.012 * s), pos=(0.325 * s, -0.006 * s, 0), euler=(1.57, 0, 0))
        fixture.collision("cylinder", (0.013 * s, 0.047 * s), pos=(0.325 * s, -0.065 * s, 0), euler=(1.57, 0, 0))
        fixture.collision("cylinder", (0.019 * s, 0.075 * s), pos=(0.381 * s, -0.12 * s, 0), euler=(0, 1.57, 0))
        fixture.site("grip", pos=(_HANDLE_GRIP_X * s, _HANDLE_BAR_Y * s, 0))
        fixture.close_body()
        fixture.close_body()
        return fixture.build()

    def _setup_task_references(self) -> None:
        self.door_root_ids = {name: self.body_id(f"{name}_door_main") for name in DOOR_NAMES}

    def _place_instance(self, rng: np.random.Generator) -> None:
        for name in DOOR_NAMES:
            x, y = self.hinge_xy[name]
            jitter = rng.uniform(-self.placement_jitter_m, self.placement_jitter_m, size=2)
            self.set_fixture_pose(self.door_root_ids[name], (x + jitter[0], y + jitter[1], self.table_offset[2]))
            self.set_joint_value(self.hinge_joint(name), 0.0)

    # ------------------------------------------------------------------ geometry the success test and expert read
    @staticmethod
    def hinge_joint(door: str) -> str:
        return f"{door}_door_hinge"

    def door_yaw(self, door: str) -> float:
        """Rotation of the door about the world's +z axis since it was closed (the hinge axis may point down)."""
        joint_id = self.sim.model.joint_name2id(self.hinge_joint(door))
        return self.joint_value(self.hinge_joint(door)) * float(np.sign(self.sim.data.xaxis[joint_id][2]))

    def opening_angle(self, door: str) -> float:
        """Signed opening, positive when the door swung away from the robot (pushed), negative when pulled.

        The right door's free edge points to -y and the left door's to +y, so pushing is a positive yaw for the
        right door and a negative yaw for the left one.
        """
        return self.door_yaw(door) * OPENING_PER_YAW[door]

    def hinge_position(self, door: str) -> np.ndarray:
        return np.array(self.sim.data.xpos[self.body_id(f"{door}_door_door_link")])

    def handle_grip_position(self, door: str) -> np.ndarray:
        return np.array(self.sim.data.site_xpos[self.sim.model.site_name2id(f"{door}_door_grip")])

    @property
    def handle_bar_offset_m(self) -> float:
        """Distance from the handle bar's axis to the door plane."""
        return -_HANDLE_BAR_Y * DOOR_SCALE

    @property
    def handle_bar_radius_m(self) -> float:
        return _HANDLE_BAR_RADIUS * DOOR_SCALE

    # ------------------------------------------------------------------ success
    def _goal_reached(self, variation: Variation) -> bool:
        angle = self.opening_angle(variation.params["door"])
        return angle > SUCCESS_ANGLE_RAD if variation.params["swing"] == "push" else angle < -SUCCESS_ANGLE_RAD
