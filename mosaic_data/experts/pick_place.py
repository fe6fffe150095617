"""Pick-place expert: a top-down grasp of the asked item near its top, carried high over the other items and
the bin walls, lowered into the asked bin and let go.

Both hands close along their world y axis when pointing straight down, so the hand turns with the item's yaw
and closes along the item's own y axis, its narrow side (4 cm for the milk carton and the bread loaf, 3 cm
for the cereal box, 5 cm for the round can; the Sawyer's fingers open to 6 cm), which the scene turns towards
the robot: the hands, long along their closing direction, then reach in between the items. Of the two hand
yaws that close along that axis, the expert takes the one near -90 degrees, where the Sawyer tracks best.

The hand turns on the spot first (turning while reaching over the items flips the arms' wrists), then
settles a few centimetres above the item until it is at rest (the Sawyer's tracking error is integrated out
there), then goes slowly straight down to the grasp point read at that moment. The Sawyer drifts about a
centimetre along x (the closing direction) when it starts to move down, twice the 5 mm the fingers clear the
round can by on either side, so a fingertip would land on the can's rim and tip it over; until the fingertips
are below the item's top the descent pauses whenever the hand is more than a few millimetres off the grasp point
in x and y, and goes on once the tracking offset has pulled it back. Carry and place targets are read from
the item's actual pose in the hand, so an item that slipped in the fingers still lands inside the bin. If the
item is not in the hand after the lift, the expert starts over, at most ``MAX_RETRIES`` times.
"""

from __future__ import annotations

import numpy as np

from mosaic_data.experts.base import GRIPPER_CLOSED, GRIPPER_OPEN, GraspingExpert, Phase, top_down
from mosaic_data.tasks.pick_place import PickPlace

APPROACH_HEIGHT_M = 0.10
"""Hover height above the item's top before going down."""
HOVER_HEIGHT_M = 0.06
"""Height above the grasp point where the hand settles before the fingers go down around the item."""
GRASP_DEPTH_M = 0.03
"""The grip site goes this far below the item's top (at most to the item's middle)."""
CARRY_CLEARANCE_M = 0.17
"""Height of the carried item's bottom above the table: over the tallest item (15 cm) and the bin walls."""
PLACE_HEIGHT_M = 0.015
"""The item's bottom is lowered to this far above the bin floor (or until it touches the bin) before release."""
LIFTED_M = 0.03
"""The item counts as in the hand when its bottom is this far above the table after the lift."""
MAX_RETRIES = 2
TURNED_RAD = 0.25
TURN_RISE_M = 0.05
"""The hand rises this much while it turns on the spot before the approach."""
SETTLED_M = 0.004
SETTLED_SPEED_M = 0.002
"""Largest move of the grip site in one control step for the hand to count as at rest."""
FINGERTIP_BELOW_M = 0.02
"""The fingertips reach about this far below the grip site (plus a margin)."""
DESCEND_ALIGNED_M = 0.003
"""While the fingertips are above the item, the hand goes down only while this close to the grasp point in x and y."""
DESCEND_STEP_M = 0.003
"""Slow descent: the Sawyer's sideways drift grows with the speed it goes down at."""
DESCEND_MAX_STEPS = 60
DESCEND_TOLERANCE_M = 0.006


HAND_YAW_CENTRE_RAD = {"panda": -np.pi / 2, "sawyer": -np.pi / 2}
"""Of the two hand yaws that close along the item's y axis, each robot takes the one nearest this."""


def _hand_yaw(item_yaw: float, centre: float) -> float:
    """The yaw within a quarter turn of ``centre`` that closes the hand along the item's y axis."""
    return (item_yaw - centre + np.pi / 2) % np.pi - np.pi / 2 + centre


class PickPlaceExpert(GraspingExpert):
    env: PickPlace

    max_offset_m: float = 0.07
    """The Sawyer lags its target by up to 5 cm near its base, where the items stand."""

    max_retries = MAX_RETRIES

    def _item_bottom_z(self) -> float:
        item = self.variation.params["item"]
        return float(self.env.item_position(item)[2] + self.env.item_extents[item][0][2])

    def holding(self) -> bool:
        item = self.variation.params["item"]
        lifted = self._item_bottom_z() - self.env.table_offset[2]
        return bool(lifted > LIFTED_M and self.env.check_contact(self.env.robot.gripper["right"], self.env.items[item]))

    def phases(self) -> list[Phase]:
        env = self.env
        item = self.variation.params["item"]
        bin_name = self.variation.params["bin"]
        up = np.array([0.0, 0.0, 1.0])
        low, high = env.item_extents[item]
        height = high[2] - low[2]
        self.orientation = top_down(_hand_yaw(env.item_yaw(item), HAND_YAW_CENTRE_RAD[env.robot_key]))
        start = env.item_position(item)
        grasp_z = start[2] + high[2] - min(GRASP_DEPTH_M, height / 2)
        table_z = env.table_offset[2]

        def grasp_point() -> np.ndarray:
            """The item's current position in x and y (it may have been nudged), the grasp height."""
            p = env.item_position(item)
            return np.array([p[0], p[1], grasp_z])

        def hand_for_bottom_at(goal: np.ndarray) -> np.ndarray:
            """Where the grip site must go for the held item's bottom centre to be at ``goal``."""
            bottom = env.item_position(item) + up * low[2]
            return env.eef_pos + (goal - bottom)

        def over_bin(height_above_floor: float) -> np.ndarray:
            return hand_for_bottom_at(env.bin_position(bin_name) + up * height_above_floor)

        carry_height = table_z + CARRY_CLEARANCE_M - env.bin_position(bin_name)[2]

        def touching() -> bool:
            return env.check_contact(env.items[item], env.bins[bin_name])

        lift_dz = table_z + CARRY_CLEARANCE_M - (start[2] + low[2])

        def hover() -> np.ndarray:
            return grasp_point() + up * HOVER_HEIGHT_M

        last_position: list[np.ndarray] = []

        def settled() -> bool:
            """Over the item within ``SETTLED_M`` and at rest: the Sawyer sways by centimetres after a move."""
            position = env.eef_pos
            still = bool(last_position) and np.linalg.norm(position - last_position[0]) < SETTLED_SPEED_M
            last_position[:] = [position]
            error = position - hover()
            return still and np.linalg.norm(error[:2]) < SETTLED_M and abs(error[2]) < 0.01

        item_top_z = start[2] + high[2]
        descend_goal = self.frozen("descend", grasp_point)

        def descend_target() -> np.ndarray:
            """Straight down to the grasp point, pausing while the fingertips are above the item and the hand is
            off the grasp point: the Sawyer drifts sideways when it moves down, and the fingers clear the can by
            only half a centimetre on either side."""
            goal = descend_goal()
            position = env.eef_pos
            above = position[2] > item_top_z + FINGERTIP_BELOW_M
            if above and np.linalg.norm(position[:2] - goal[:2]) > DESCEND_ALIGNED_M:
                return np.array([goal[0], goal[1], max(self._command_pos[2], goal[2])])
            return goal

        def at_grasp_point() -> bool:
            return bool(np.linalg.norm(env.eef_pos - descend_goal()) < DESCEND_TOLERANCE_M)

        def turned() -> bool:
            return bool((env.eef_rotation.inv() * self.orientation).magnitude() < TURNED_RAD)

        return [
            # Turn the hand on the spot first: turning while reaching over the items makes the arms' wrists flip.
            # Rising while it turns: the hand keeps moving, and further from the items.
            Phase(
                "turn", self.frozen("turn", lambda: env.eef_pos + up * TURN_RISE_M), GRIPPER_OPEN, tolerance_m=0.0,
                done=turned, max_steps=20, paced=True,
            ),
            Phase("approach", lambda: grasp_point() + up * (height - GRASP_DEPTH_M + APPROACH_HEIGHT_M), GRIPPER_OPEN, tolerance_m=0.02, max_steps=60, max_step_m=0.02),
            # Settle above the item: the Sawyer's lag changes on the way and must be integrated out before the
            # fingers go down on either side of the item.
            Phase("align", hover, GRIPPER_OPEN, tolerance_m=0.0, done=settled, min_steps=3, max_steps=40, max_step_m=0.01),
            # The hold target of a paused descent is where the hand is: done only at the real grasp point.
            Phase(
                "descend", descend_target, GRIPPER_OPEN, tolerance_m=0.0, done=at_grasp_point,
                max_steps=DESCEND_MAX_STEPS, max_step_m=DESCEND_STEP_M,
            ),
            self.grasp_phase("grasp", self.frozen("grasp", grasp_point)),
            Phase("lift", self.frozen("lift", lambda: env.eef_pos + up * lift_dz), GRIPPER_CLOSED, tolerance_m=0.02, max_steps=40, max_step_m=0.01),
            Phase("carry", lambda: over_bin(carry_height), GRIPPER_CLOSED, tolerance_m=0.015, max_steps=60, max_step_m=0.02),
            Phase("lower", lambda: over_bin(PLACE_HEIGHT_M), GRIPPER_CLOSED, tolerance_m=0.006, done=touching, max_steps=40, max_step_m=0.01),
            Phase("release", self.frozen("release", lambda: env.eef_pos), GRIPPER_OPEN, tolerance_m=0.0, min_steps=8, max_steps=8),
            Phase(
                "retreat", self.frozen("retreat", lambda: env.eef_pos + up * APPROACH_HEIGHT_M), GRIPPER_OPEN,
                tolerance_m=0.02, max_steps=30, max_step_m=0.01,
            ),
        ]
