"""Stack block: three cubes of different colours on the table; stack one of them on another.

Variation ``i`` is the ``i``-th permutation (in :func:`itertools.permutations` order) of the three colours
as (cube A to pick up, cube B to stack it on, distractor C):

====  =====  =====  =====  ======================================
 i    A      B      C      description
====  =====  =====  =====  ======================================
 0    red    green  blue   stack the red block on the green block
 1    red    blue   green  stack the red block on the blue block
 2    green  red    blue   stack the green block on the red block
 3    green  blue   red    stack the green block on the blue block
 4    blue   red    green  stack the blue block on the red block
 5    blue   green  red    stack the blue block on the green block
====  =====  =====  =====  ======================================

The cubes are robosuite :class:`~robosuite.models.objects.BoxObject` s (``CUBE_HALF_SIZE_M`` half-size, free
joints). Every instance places all three at random, non-overlapping spots in a region in front of the robot
(at least ``MIN_CUBE_DISTANCE_M`` apart, so a hand fits between them), each turned by a random yaw; the
colours' spots are shuffled by the same draw, so only the variation (its description) says which cube goes
where.

Success: cube A rests on cube B (they touch, A's bottom is within ``STACK_HEIGHT_TOLERANCE_M`` of B's top and
A's centre lies within half a cube of B's centre in x and y) and the gripper has let go of A (no contact
between the gripper and A). Stacking A on C, or another cube on B, is a failure.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from robosuite.models.objects import BoxObject
from scipy.spatial.transform import Rotation

from mosaic_data.tasks.base import MosaicTaskEnv, Variation
from mosaic_data.tasks.spec import CUBE_NAMES, TASK_SPECS

CUBE_COLOURS: dict[str, tuple[float, float, float, float]] = {
    "red": (0.85, 0.1, 0.1, 1.0),
    "green": (0.1, 0.7, 0.15, 1.0),
    "blue": (0.12, 0.25, 0.9, 1.0),
}
CUBE_HALF_SIZE_M = 0.021
MIN_CUBE_DISTANCE_M = 0.11
"""Centre-to-centre distance between any two cubes at the start of an instance."""
STACK_HEIGHT_TOLERANCE_M = 0.012
"""How far A's bottom may be from B's top (cubes settle into each other by a few millimetres)."""


class StackBlock(MosaicTaskEnv):
    task_name: ClassVar[str] = "stack_block"
    variations: ClassVar[tuple[Variation, ...]] = TASK_SPECS["stack_block"].variations
    horizon_steps: ClassVar[int] = TASK_SPECS["stack_block"].horizon_steps
    # Region (x, y ranges) where the cubes' centres are drawn, in front of the robot.
    placement_x_range: ClassVar[tuple[float, float]] = (-0.08, 0.12)
    placement_y_range: ClassVar[tuple[float, float]] = (-0.18, 0.18)

    def _load_task_objects(self) -> list:
        h = CUBE_HALF_SIZE_M
        self.cubes = {
            name: BoxObject(name=f"{name}_cube", size=(h, h, h), rgba=rgba, friction=(1.0, 0.005, 0.0001))
            for name, rgba in CUBE_COLOURS.items()
        }
        return list(self.cubes.values())

    def _setup_task_references(self) -> None:
        self.cube_body_ids = {name: self.body_id(cube.root_body) for name, cube in self.cubes.items()}

    def _place_instance(self, rng: np.random.Generator) -> None:
        positions: list[np.ndarray] = []
        while len(positions) < len(CUBE_NAMES):
            candidate = np.array([rng.uniform(*self.placement_x_range), rng.uniform(*self.placement_y_range)])
            if all(np.linalg.norm(candidate - other) >= MIN_CUBE_DISTANCE_M for other in positions):
                positions.append(candidate)
            elif len(positions) > 0 and rng.uniform() < 0.02:
                positions.clear()  # a start that leaves no room: draw all spots again
        yaws = rng.uniform(-np.pi / 4, np.pi / 4, size=len(CUBE_NAMES))
        z = self.table_offset[2] + CUBE_HALF_SIZE_M
        for (name, cube), xy, yaw in zip(self.cubes.items(), positions, yaws):
            quat = Rotation.from_euler("z", yaw).as_quat(scalar_first=True)
            self.sim.data.set_joint_qpos(cube.joints[0], np.concatenate([xy, [z], quat]))

    # ------------------------------------------------------------------ geometry the success test and expert read
    def cube_position(self, name: str) -> np.ndarray:
        return np.array(self.sim.data.xpos[self.cube_body_ids[name]])

    def cube_yaw(self, name: str) -> float:
        """The cube's yaw about world z, folded into [-pi/4, pi/4) (a cube looks the same every quarter turn)."""
        matrix = self.sim.data.xmat[self.cube_body_ids[name]].reshape(3, 3)
        yaw = float(np.arctan2(matrix[1, 0], matrix[0, 0]))
        return (yaw + np.pi / 4) % (np.pi / 2) - np.pi / 4

    def is_stacked(self, picked: str, base: str) -> bool:
        """``picked`` rests on ``base`` (touching, bottom on top, centred within half a cube)."""
        top, bottom = self.cube_position(picked), self.cube_position(base)
        height_error = (top[2] - bottom[2]) - 2 * CUBE_HALF_SIZE_M
        centred = np.all(np.abs(top[:2] - bottom[:2]) < CUBE_HALF_SIZE_M)
        return bool(
            abs(height_error) < STACK_HEIGHT_TOLERANCE_M
            and centred
            and self.check_contact(self.cubes[picked], self.cubes[base])
        )

    def is_released(self, name: str) -> bool:
        return not self.check_contact(self.robot.gripper["right"], self.cubes[name])

    # ------------------------------------------------------------------ success
    def _goal_reached(self, variation: Variation) -> bool:
        picked = variation.params["picked"]
        return self.is_stacked(picked, variation.params["base"]) and self.is_released(picked)
