"""Door expert: reach the handle bar past the door's free edge, then swing it about the hinge.

The fingers close at the start and stay closed (they push and hook, they never grasp), and the approach is
paced so that the hand arrives above the handle as its turn ends: the motion has no stop whose only change is
one a camera frame barely shows (fingers closing in the air, a wrist finishing its turn), where a policy that
sees one frame would not know whether to go on.

Push: the closed fingers go down just in front of the bar and press its robot-side face.
Pull: the closed fingers go straight down into the gap between the bar and the door plane (past the door's
free edge nothing stands behind the bar) and hook the bar's back.
The target is then the contact point rotated a little further than the door's current angle about the
hinge, so the hand follows the door's arc instead of fighting the hinge, and the hand turns with the door so
that its long side stays along the door plane.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mosaic_data.experts.base import GRIPPER_CLOSED, Phase, ScriptedExpert, top_down
from mosaic_data.tasks.door import OPENING_PER_YAW, SUCCESS_ANGLE_RAD, Door

APPROACH_HEIGHT_M = 0.12
"""Above the handle bar, where the descent starts; the door's top edge is 0.074 m above the bar."""
PUSH_STANDOFF_M = 0.04
"""Gap between the fingers and the bar's robot-side face when they go down (push)."""
PULL_GAP_FRACTION = 0.5
"""Where the fingers go down between the door plane (0) and the bar's axis (1) (pull)."""
PULL_OUTWARD_M = 0.02
"""How far past the grip point, towards the bar's free end, the fingers go down (pull): clear of the door's edge."""
PRESS_M = 0.006
"""How far past the bar's surface the contact target lies, so the fingers keep pressing it."""
ENGAGED_ANGLE_RAD = 0.03
"""The fingers are on the bar once the door has turned this much."""
LEAD_ANGLE_RAD = 0.25
TARGET_ANGLE_RAD = SUCCESS_ANGLE_RAD + 0.2
SETTLED_TURN_RAD = 0.1
LOWER_M = 0.04
LOWER_STEP_M = 0.004
LOWERED_TOLERANCE_M = 0.015
"""The approach's command ends above the handle; the first ``LOWER_M`` down go at ``LOWER_STEP_M`` per step
while the arm, lagging the command by centimetres, catches up and finishes its turn (within
``LOWERED_TOLERANCE_M`` and ``SETTLED_TURN_RAD``). The command keeps moving: a policy seeing one frame cannot
tell a stop to settle from an arrival."""
HAND_YAW_RAD = {"left": np.pi / 2, "right": -np.pi / 2}
"""Top-down hand turned so that the fingers spread along the closed door's plane, the hand's x axis pointing
to the door's free edge (mirror-symmetric for the mirrored doors)."""


class DoorExpert(ScriptedExpert):
    env: Door

    def phases(self) -> list[Phase]:
        door = self.variation.params["door"]
        hand_yaw = HAND_YAW_RAD[door]
        self.orientation = top_down(hand_yaw)
        sign = 1.0 if self.variation.params["swing"] == "push" else -1.0
        env = self.env
        hinge = env.hinge_position(door)
        grip = env.handle_grip_position(door)
        yaw_sign = sign * OPENING_PER_YAW[door]  # which way the door turns about world z
        angle0 = env.door_yaw(door)
        opening0 = env.opening_angle(door)
        # Robot-side normal of the door plane at the door's current angle.
        normal = Rotation.from_euler("z", angle0).apply([-1.0, 0.0, 0.0])
        bar_radius = env.handle_bar_radius_m
        if sign > 0:  # in front of the bar, then press its robot-side face
            down = grip + normal * (bar_radius + PUSH_STANDOFF_M)
            contact = grip + normal * (bar_radius - PRESS_M)
        else:  # in the gap behind the bar, towards its free end (away from the door's edge), then hook its back
            along_door = grip - hinge
            along_door[2] = 0.0
            along_door -= normal * np.dot(along_door, normal)
            along_door /= np.linalg.norm(along_door)
            down = grip - normal * (env.handle_bar_offset_m * PULL_GAP_FRACTION) + along_door * PULL_OUTWARD_M
            contact = grip - normal * (bar_radius - PRESS_M)
        for point in (down, contact):
            point[2] -= 0.005
        contact_local = Rotation.from_euler("z", -angle0).apply(contact - hinge)
        above = down + np.array([0.0, 0.0, APPROACH_HEIGHT_M])

        def on_arc(angle: float) -> np.ndarray:
            return hinge + Rotation.from_euler("z", angle).apply(contact_local)

        def follow_door(offset_rad: float) -> np.ndarray:
            yaw = env.door_yaw(door)
            self.orientation = top_down(hand_yaw + yaw - angle0)
            return on_arc(yaw + offset_rad)

        lowered = above - np.array([0.0, 0.0, LOWER_M])

        def turned_over(point: np.ndarray):
            """Over the handle and turned: turning the wrist fast on the way down would throw the fingers off."""

            def check() -> bool:
                turned = (env.eef_rotation.inv() * self.orientation).magnitude() < SETTLED_TURN_RAD
                return turned and np.linalg.norm(env.eef_pos - point) < LOWERED_TOLERANCE_M

            return check

        def swung_enough() -> bool:
            return sign * env.opening_angle(door) > TARGET_ANGLE_RAD

        return [
            Phase(
                "approach", lambda: above, GRIPPER_CLOSED, tolerance_m=0.0, done=self.command_arrived(lambda: above),
                max_steps=60, paced=True,
            ),
            # The first centimetres down are slow, for the arm to catch up with the command and finish its turn.
            Phase(
                "lower", lambda: lowered, GRIPPER_CLOSED, tolerance_m=0.0, done=turned_over(lowered), max_steps=25,
                max_step_m=LOWER_STEP_M,
            ),
            Phase("descend", lambda: down, GRIPPER_CLOSED, tolerance_m=0.012, max_steps=40, max_step_m=0.01),
            Phase(
                "engage",
                lambda: contact,
                GRIPPER_CLOSED,
                tolerance_m=0.012,
                done=lambda: sign * (env.opening_angle(door) - opening0) > ENGAGED_ANGLE_RAD,
                max_steps=15,
                max_step_m=0.006,
            ),
            Phase(
                "swing",
                lambda: follow_door(yaw_sign * LEAD_ANGLE_RAD),
                GRIPPER_CLOSED,
                tolerance_m=0.0,
                done=swung_enough,
                max_steps=80,
                max_step_m=0.01,
            ),
            Phase(
                "retreat",
                lambda: follow_door(-yaw_sign * 0.05) + np.array([0.0, 0.0, APPROACH_HEIGHT_M]),
                GRIPPER_CLOSED,
                tolerance_m=0.02,
                max_steps=30,
            ),
        ]
