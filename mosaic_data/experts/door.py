"""Door expert: reach the handle bar past the door's free edge, then swing it about the hinge.

Push: the open fingers press the bar's robot-side face and the target circles away from the robot.
Pull: the open fingers drop into the gap between the bar and the door plane and hook the bar back.
The target is always the contact point rotated a little further than the door's current angle about the
hinge, so the hand follows the door's arc instead of fighting the hinge.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mosaic_data.experts.base import GRIPPER_OPEN, Phase, ScriptedExpert, top_down
from mosaic_data.tasks.door import SUCCESS_ANGLE_RAD, Door

APPROACH_HEIGHT_M = 0.10
LEAD_ANGLE_RAD = 0.25
TARGET_ANGLE_RAD = SUCCESS_ANGLE_RAD + 0.2


class DoorExpert(ScriptedExpert):
    env: Door

    def phases(self) -> list[Phase]:
        # Fingers spread along the door plane, so the wide hand stays on the robot's side of the door.
        self.orientation = top_down(np.pi / 2)
        door = self.variation.params["door"]
        sign = 1.0 if self.variation.params["swing"] == "push" else -1.0
        env = self.env
        hinge = env.hinge_position(door)
        grip = env.handle_grip_position(door)
        angle0 = env.opening_angle(door)
        # Robot-side normal of the door plane at the door's current angle.
        normal = Rotation.from_euler("z", angle0).apply([-1.0, 0.0, 0.0])
        if sign > 0:  # in front of the bar, on the robot's side
            contact = grip + normal * (env.handle_bar_radius_m + 0.022)
        else:  # between the bar and the door plane
            contact = grip - normal * (env.handle_bar_offset_m * 0.5)
        contact[2] -= 0.005
        contact_local = Rotation.from_euler("z", -angle0).apply(contact - hinge)

        def on_arc(angle: float) -> np.ndarray:
            return hinge + Rotation.from_euler("z", angle).apply(contact_local)

        def swing_target() -> np.ndarray:
            return on_arc(env.opening_angle(door) + sign * LEAD_ANGLE_RAD)

        def swung_enough() -> bool:
            return sign * env.opening_angle(door) > TARGET_ANGLE_RAD

        above = contact + np.array([0.0, 0.0, APPROACH_HEIGHT_M])
        return [
            Phase("approach", lambda: above, GRIPPER_OPEN, tolerance_m=0.02, max_steps=60),
            Phase("descend", lambda: contact, GRIPPER_OPEN, tolerance_m=0.01, max_steps=40, max_step_m=0.01),
            Phase("swing", swing_target, GRIPPER_OPEN, tolerance_m=0.0, done=swung_enough, max_steps=80, max_step_m=0.01),
            Phase(
                "retreat",
                lambda: on_arc(env.opening_angle(door) - sign * 0.05) + np.array([0.0, 0.0, APPROACH_HEIGHT_M]),
                GRIPPER_OPEN,
                tolerance_m=0.02,
                max_steps=30,
            ),
        ]
