"""Nut assembly: three coloured nuts and three pegs on the table; put one nut on one peg.

Variation ``i``: nut ``i // 3`` (by colour) and peg ``i % 3`` (by position along the row; left = +y, the
robot's left):

====  =====  ======  =================================
 i    nut    peg     description
====  =====  ======  =================================
 0    blue   left    put the blue nut on the left peg
 1    blue   middle  put the blue nut on the middle peg
 2    blue   right   put the blue nut on the right peg
 3    red    left    put the red nut on the left peg
 4    red    middle  put the red nut on the middle peg
 5    red    right   put the red nut on the right peg
 6    green  left    put the green nut on the left peg
 7    green  middle  put the green nut on the middle peg
 8    green  right   put the green nut on the right peg
====  =====  ======  =================================

The nuts are robosuite's :class:`~robosuite.models.objects.RoundNutObject` (a ring with a handle, free joint),
recoloured. The pegs are robosuite's round peg of the ``PegsArena`` (its cylinder's radius and height, read from
that arena), three of them standing in a row along y on a small base plate, far from the robot; each instance
jitters every peg by up to ``PEG_JITTER_M``. Every instance places the three nuts at random, non-overlapping
spots in a region in front of the robot (at least ``MIN_NUT_DISTANCE_M`` apart), with their handles pointing
away from the robot, towards the pegs, turned by a random yaw of up to ``NUT_YAW_RANGE_RAD``; which colour lies where is part of
the same draw, so only the variation (its description) says which nut goes where.

Success: the asked nut is down around the asked peg (its centre within ``ON_PEG_RADIUS_M`` of the peg's axis
and at most ``ON_PEG_HEIGHT_M`` above the table, i.e. threaded and resting near the peg's base), no other nut
is on that peg, and the gripper has let go of the nut (no contact between the gripper and it). The asked nut
on another peg, or another nut on the asked peg, is a failure.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from robosuite.models.arenas import PegsArena
from robosuite.models.objects import RoundNutObject
from scipy.spatial.transform import Rotation

from mosaic_data.tasks.base import MosaicTaskEnv, Variation
from mosaic_data.tasks.fixtures import FixtureBuilder
from mosaic_data.tasks.spec import NUT_NAMES, PEG_NAMES, TASK_SPECS

NUT_COLOURS: dict[str, tuple[float, float, float, float]] = {
    "blue": (0.15, 0.3, 0.95, 1.0),
    "red": (0.9, 0.12, 0.1, 1.0),
    "green": (0.1, 0.75, 0.2, 1.0),
}


ROBOSUITE_NUT_ASSEMBLY_TABLE_Z = 0.82
"""Table-top height of robosuite's ``NutAssembly`` (its default ``table_offset``); its pegs stand on it."""


def _robosuite_round_peg() -> tuple[float, float, float]:
    """(radius, height above the table top, z of the cylinder's centre above the table top) of robosuite's round
    peg, as its ``PegsArena`` and ``NutAssembly`` (table top at ``ROBOSUITE_NUT_ASSEMBLY_TABLE_Z``) place it."""
    body = PegsArena().peg2_body
    geom = body.find("geom")
    radius, half_height = (float(v) for v in geom.get("size").split())
    centre_above_table = float(body.get("pos").split()[2]) - ROBOSUITE_NUT_ASSEMBLY_TABLE_Z
    return radius, centre_above_table + half_height, centre_above_table


PEG_RADIUS_M, PEG_HEIGHT_M, _PEG_CENTRE_Z_M = _robosuite_round_peg()
"""robosuite's round peg: radius 0.02 m, standing 0.13 m above the table (its bottom sinks into the table)."""
NUT_HALF_THICKNESS_M = 0.01
"""Half thickness of the nut's ring and handle (robosuite's round-nut geometry)."""
NUT_HANDLE_OFFSET_M = 0.06
"""Distance from the nut's centre to its handle's centre along the nut's local +x (robosuite's round nut)."""
NUT_INNER_RADIUS_M = 0.0312
"""Radius of the nut's hole (its inner faces), about 11 mm wider than the peg."""
MIN_NUT_DISTANCE_M = 0.155
"""Centre-to-centre distance between any two nuts at the start (ring 0.054 m, handle reaching 0.085 m)."""
NUT_YAW_RANGE_RAD = 0.5
"""Handles point away from the robot (+x), turned by a yaw drawn in [-range, range]."""
PEG_JITTER_M = 0.015
ON_PEG_RADIUS_M = 0.02
"""The nut's centre within this of the peg's axis: only a nut threaded on the peg can be there."""
ON_PEG_HEIGHT_M = 0.05
"""The nut's centre at most this above the table: down at the peg's base (resting, it is 0.01 m)."""


class ColouredRoundNut(RoundNutObject):
    """robosuite's round nut with its metal material tinted ``rgba`` (texture dropped, so the colour is plain)."""

    def __init__(self, name: str, rgba) -> None:
        super().__init__(name=name)
        for material in self.asset.iter("material"):
            material.attrib.pop("texture", None)
            material.set("rgba", " ".join(f"{c:g}" for c in rgba))
            material.set("reflectance", "0.1")
            material.set("shininess", "0.4")
            material.set("specular", "0.4")


class NutAssembly(MosaicTaskEnv):
    task_name: ClassVar[str] = "nut_assembly"
    variations: ClassVar[tuple[Variation, ...]] = TASK_SPECS["nut_assembly"].variations
    horizon_steps: ClassVar[int] = TASK_SPECS["nut_assembly"].horizon_steps
    # Where each peg's axis stands (x, y) at the centre of the instance distribution.
    peg_xy: ClassVar[dict[str, tuple[float, float]]] = {"left": (0.09, 0.18), "middle": (0.09, 0.0), "right": (0.09, -0.18)}
    # Region (x, y ranges) where the nuts' centres are drawn, in front of the robot.
    placement_x_range: ClassVar[tuple[float, float]] = (-0.2, -0.09)
    placement_y_range: ClassVar[tuple[float, float]] = (-0.22, 0.22)

    def _load_task_objects(self) -> list:
        self.nuts = {name: ColouredRoundNut(f"{name}_nut", rgba) for name, rgba in NUT_COLOURS.items()}
        return [self._build_peg(name) for name in PEG_NAMES] + list(self.nuts.values())

    @staticmethod
    def _build_peg(name: str):
        fixture = FixtureBuilder(f"{name}_peg")
        steel = fixture.material("steel", (0.62, 0.64, 0.68, 1.0), texture="metal1.png", shininess=0.8)
        base = fixture.material("base", (0.25, 0.25, 0.28, 1.0))
        # Fixture origin on the peg's axis at table height.
        fixture.solid_box((0.035, 0.035, 0.003), base, pos=(0, 0, 0.003), mass=0.5)
        centre = (0, 0, _PEG_CENTRE_Z_M)
        size = (PEG_RADIUS_M, PEG_HEIGHT_M - _PEG_CENTRE_Z_M)
        fixture.raw(
            f'<geom type="cylinder" size="{size[0]:g} {size[1]:g}" pos="0 0 {centre[2]:g}" material="{steel}" '
            'group="1" contype="0" conaffinity="0" mass="0"/>'
        )
        fixture.collision("cylinder", size, pos=centre, mass=0.5, name="peg")
        return fixture.build()

    def _setup_task_references(self) -> None:
        self.peg_root_ids = {name: self.body_id(f"{name}_peg_main") for name in PEG_NAMES}
        self.nut_body_ids = {name: self.body_id(nut.root_body) for name, nut in self.nuts.items()}
        self.nut_handle_site_ids = {
            name: self.sim.model.site_name2id(nut.important_sites["handle"]) for name, nut in self.nuts.items()
        }

    def _place_instance(self, rng: np.random.Generator) -> None:
        for name in PEG_NAMES:
            x, y = self.peg_xy[name]
            jitter = rng.uniform(-PEG_JITTER_M, PEG_JITTER_M, size=2)
            self.set_fixture_pose(self.peg_root_ids[name], (x + jitter[0], y + jitter[1], self.table_offset[2]))
        positions: list[np.ndarray] = []
        while len(positions) < len(NUT_NAMES):
            candidate = np.array([rng.uniform(*self.placement_x_range), rng.uniform(*self.placement_y_range)])
            if all(np.linalg.norm(candidate - other) >= MIN_NUT_DISTANCE_M for other in positions):
                positions.append(candidate)
            elif positions and rng.uniform() < 0.05:
                positions.clear()  # a start that leaves no room: draw all spots again
        yaws = rng.uniform(-NUT_YAW_RANGE_RAD, NUT_YAW_RANGE_RAD, size=len(NUT_NAMES))
        z = self.table_offset[2] + NUT_HALF_THICKNESS_M
        for (name, nut), xy, yaw in zip(self.nuts.items(), positions, yaws):
            quat = Rotation.from_euler("z", yaw).as_quat(scalar_first=True)
            self.sim.data.set_joint_qpos(nut.joints[0], np.concatenate([xy, [z], quat]))

    # ------------------------------------------------------------------ geometry the success test and expert read
    def nut_position(self, nut: str) -> np.ndarray:
        """Centre of the nut's ring."""
        return np.array(self.sim.data.xpos[self.nut_body_ids[nut]])

    def nut_rotation(self, nut: str) -> Rotation:
        return Rotation.from_matrix(self.sim.data.xmat[self.nut_body_ids[nut]].reshape(3, 3))

    def nut_velocity(self, nut: str) -> np.ndarray:
        """Linear velocity (m/s) of the nut's centre."""
        return np.array(self.sim.data.get_joint_qvel(self.nuts[nut].joints[0])[:3])

    def nut_handle_position(self, nut: str) -> np.ndarray:
        return np.array(self.sim.data.site_xpos[self.nut_handle_site_ids[nut]])

    def peg_position(self, peg: str) -> np.ndarray:
        """Point of the peg's axis at table height."""
        return np.array(self.sim.data.xpos[self.peg_root_ids[peg]])

    def peg_top_z(self, peg: str) -> float:
        return float(self.peg_position(peg)[2] + PEG_HEIGHT_M)

    def is_on_peg(self, nut: str, peg: str) -> bool:
        """``nut`` is threaded on ``peg`` and down near its base."""
        centre, axis = self.nut_position(nut), self.peg_position(peg)
        return bool(
            np.linalg.norm(centre[:2] - axis[:2]) < ON_PEG_RADIUS_M and centre[2] - axis[2] < ON_PEG_HEIGHT_M
        )

    def is_released(self, nut: str) -> bool:
        return not self.check_contact(self.robot.gripper["right"], self.nuts[nut])

    # ------------------------------------------------------------------ success
    def _goal_reached(self, variation: Variation) -> bool:
        nut, peg = variation.params["nut"], variation.params["peg"]
        others_on_peg = any(self.is_on_peg(other, peg) for other in NUT_NAMES if other != nut)
        return self.is_on_peg(nut, peg) and not others_on_peg and self.is_released(nut)
