"""Stack-block expert: a top-down grasp of cube A, carried over cube B, lowered onto it and let go.

The hand turns with cube A's yaw so the fingers close on two opposite faces, and while carrying it turns on by
the difference between A's and B's yaw, so A lands square on B. The hand first settles a few centimetres above
A (the Sawyer's tracking error is integrated out there), then goes straight down following A's current
position. Carry and place targets are read from A's actual pose in the hand, so a cube that slipped in the
fingers still lands on B. If A is not in the hand after the lift (a finger landed on it, it slipped out), the
expert starts over from the approach, at most ``MAX_RETRIES`` times.
"""

from __future__ import annotations

import numpy as np

from mosaic_data.experts.base import ALIGNED_M, AT_GRASP_M, GRIPPER_CLOSED, GRIPPER_OPEN, GraspingExpert, Phase, top_down
from mosaic_data.tasks.stack_block import CUBE_HALF_SIZE_M, StackBlock

APPROACH_HEIGHT_M = 0.10
HOVER_HEIGHT_M = 0.06
"""Hover height above a grasp or place point before going down."""
"""Height above the grasp point where the hand settles before the fingers go down around the cube (the
Sawyer's fingertips reach 1.4 cm below its grip site, and it overshoots by up to 1.5 cm when it stops)."""
CARRY_HEIGHT_M = 0.12
"""Height of cube A's bottom above B's top while carrying it over."""
GRASP_BELOW_CENTRE_M = 0.004
"""The grip site goes this far below A's centre, so the finger pads hold the cube's middle."""
PLACE_DROP_M = 0.003
"""A's bottom is lowered to this far above B's top (or until they touch) before the fingers open."""
LIFTED_M = 0.03
"""A counts as in the hand when it is this far above the table after the lift."""
MAX_RETRIES = 2


def _wrap_quarter(angle: float) -> float:
    return (angle + np.pi / 4) % (np.pi / 2) - np.pi / 4


class StackBlockExpert(GraspingExpert):
    env: StackBlock

    max_offset_m: float = 0.07
    """The Sawyer lags its target by up to 4 cm over the cubes' region (more the closer to its base)."""

    max_retries = MAX_RETRIES

    def holding(self) -> bool:
        picked = self.variation.params["picked"]
        lifted = self.env.cube_position(picked)[2] - CUBE_HALF_SIZE_M - self.env.table_offset[2]
        return bool(lifted > LIFTED_M and self.env.check_contact(self.env.robot.gripper["right"], self.env.cubes[picked]))

    def phases(self) -> list[Phase]:
        env = self.env
        picked = self.variation.params["picked"]
        base = self.variation.params["base"]
        h = CUBE_HALF_SIZE_M
        up = np.array([0.0, 0.0, 1.0])
        grasp_yaw = env.cube_yaw(picked)
        place_yaw = grasp_yaw + _wrap_quarter(env.cube_yaw(base) - grasp_yaw)
        self.orientation = top_down(grasp_yaw)
        start = env.cube_position(picked)

        def grasp_point() -> np.ndarray:
            """A's current centre in x and y (it may have been nudged), its starting height."""
            a = env.cube_position(picked)
            return np.array([a[0], a[1], start[2] - GRASP_BELOW_CENTRE_M])

        def place_point(height: float) -> np.ndarray:
            """Where the grip site must go for A's bottom centre to be ``height`` above B's top centre."""
            a, b = env.cube_position(picked), env.cube_position(base)
            goal = b + up * (2 * h + height)
            return env.eef_pos + (goal - a)

        def touching() -> bool:
            return env.check_contact(env.cubes[picked], env.cubes[base])

        def hover() -> np.ndarray:
            return grasp_point() + up * HOVER_HEIGHT_M

        carry_orientation = top_down(place_yaw)
        return [
            Phase(
                "approach", lambda: grasp_point() + up * APPROACH_HEIGHT_M, GRIPPER_OPEN, tolerance_m=0.0,
                done=self.command_arrived(lambda: grasp_point() + up * APPROACH_HEIGHT_M), max_steps=60, paced=True,
            ),
            # Settle above the cube: the Sawyer's lag changes on the way and must be integrated out before the
            # fingers go down on either side of the cube.
            Phase(
                "align", hover, GRIPPER_OPEN, tolerance_m=0.0, done=self.command_arrived(hover, arm_within_m=ALIGNED_M),
                max_steps=30, max_step_m=0.006,
            ),
            # The fingers start closing once the command is at the grasp point and the arm nearly there: they take
            # a few steps to reach the cube, in which the arm settles.
            Phase(
                "descend", grasp_point, GRIPPER_OPEN, tolerance_m=0.0,
                done=self.command_arrived(grasp_point, arm_within_m=AT_GRASP_M), max_steps=30, max_step_m=0.006,
            ),
            self.grasp_phase("grasp", self.frozen("grasp", grasp_point)),
            Phase("lift", self.frozen("lift", lambda: env.eef_pos + up * CARRY_HEIGHT_M), GRIPPER_CLOSED, tolerance_m=0.02, max_steps=30, max_step_m=0.01),
            Phase(
                "carry", lambda: place_point(CARRY_HEIGHT_M), GRIPPER_CLOSED, tolerance_m=0.012, max_steps=60,
                orientation=carry_orientation,
            ),
            Phase(
                "lower", lambda: place_point(PLACE_DROP_M), GRIPPER_CLOSED, tolerance_m=0.004, done=touching,
                max_steps=40, max_step_m=0.006, orientation=carry_orientation,
            ),
            Phase("release", self.frozen("release", lambda: env.eef_pos), GRIPPER_OPEN, tolerance_m=0.0, min_steps=8, max_steps=8, orientation=carry_orientation),
            Phase(
                "retreat", lambda: env.cube_position(base) + up * (3 * h + APPROACH_HEIGHT_M), GRIPPER_OPEN, tolerance_m=0.02,
                max_steps=30, max_step_m=0.01, orientation=carry_orientation,
            ),
        ]
