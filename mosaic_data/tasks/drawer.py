"""Drawer: two two-drawer cabinets side by side on the table; open or close one of the four drawers.

Variation ``i``: drawer ``i // 2`` and goal ``i % 2`` (0 = open: pull it fully out, 1 = close: push it fully
in). Drawers, from the robot's view:

====  ==========================================  =====  ==========================================
 i    drawer                                      goal   start state of all four drawers
====  ==========================================  =====  ==========================================
 0    left drawer of the green cabinet            open   all closed
 1    left drawer of the green cabinet            close  all open
 2    right drawer of the green cabinet           open   all closed
 3    right drawer of the green cabinet           close  all open
 4    left drawer of the wooden cabinet           open   all closed
 5    left drawer of the wooden cabinet           close  all open
 6    right drawer of the wooden cabinet          open   all closed
 7    right drawer of the wooden cabinet          close  all open
====  ==========================================  =====  ==========================================

"Left" and "right" are the robot's (the agentview camera looks back at the robot from behind the
cabinets, so there they appear mirrored). The green cabinet stands on the robot's left (+y), the wooden one
on its right. Each cabinet is two of Meta-World's drawer cases joined side by side (scaled by
``DRAWER_SCALE``; handles by ``HANDLE_SCALE``, on short spacers), so that all four handles face the robot at
the same height and a top-down hand can reach each of them. Because every drawer starts in the same state,
only the variation (its description) tells which drawer to move.

Success: the asked drawer's slide is within ``SUCCESS_FRACTION`` of the asked end of its travel (open:
at least 90% out; close: at most 10% out), and every other drawer is still on its starting half of the
travel (so opening or closing the wrong drawer, or all of them, never counts).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from mosaic_data.tasks.base import MosaicTaskEnv, Variation
from mosaic_data.tasks.fixtures import FixtureBuilder
from mosaic_data.tasks.spec import CABINET_NAMES, DRAWER_SIDES, TASK_SPECS

DRAWER_SCALE = 0.75
"""Meta-World's drawer scaled so that four fit side by side in the Panda's workspace."""
SUCCESS_FRACTION = 0.9
"""Open: slide at least this fraction of its travel out; close: at most ``1 - SUCCESS_FRACTION`` out."""

HANDLE_SCALE = 1.2
HANDLE_SPACER_M = 0.015
"""The handles are scaled up from the drawers and stand on short spacers: their bar then stands far enough
off the drawer front (8.7 cm) for closed fingers to hook behind it while the hand stays in front of the
cabinet (the fingers of both robots are shorter than the drawer front is high)."""

# Geometry in Meta-World's drawer frame (x across the drawer, -y towards the robot, z up), unscaled.
_CASE_HALF_WIDTH = 0.11
_CASE_Z = 0.084
_DRAWER_Y = -0.01
_DRAWER_Z = 0.006
_TRAVEL = 0.16
_FRONT_Y = -0.09
"""Robot-side face of the drawer front, relative to the sliding drawer body."""
# Handle geometry relative to the handle mesh's origin, which sits 0.024 in front of the drawer front.
_HANDLE_MESH_Y = -0.024
_HANDLE_BAR_Y = -0.036
_HANDLE_BAR_RADIUS = 0.009
_HANDLE_POST_Y = -0.006
_HANDLE_POST_HALF_LENGTH = 0.03
_HANDLE_HALF_LENGTH = 0.05

_CABINET_MATERIALS = {
    "green": {"case": ((0.4, 0.65, 0.4, 1.0), None), "drawer": ((0.3, 0.55, 0.32, 1.0), None)},
    "wooden": {"case": ((0.62, 0.45, 0.3, 1.0), "wood2.png"), "drawer": ((0.7, 0.52, 0.36, 1.0), "wood2.png")},
}


def drawer_key(cabinet: str, side: str) -> str:
    return f"{cabinet}_{side}"


DRAWER_KEYS = tuple(drawer_key(cabinet, side) for cabinet in CABINET_NAMES for side in DRAWER_SIDES)


class Drawer(MosaicTaskEnv):
    task_name: ClassVar[str] = "drawer"
    variations: ClassVar[tuple[Variation, ...]] = TASK_SPECS["drawer"].variations
    horizon_steps: ClassVar[int] = TASK_SPECS["drawer"].horizon_steps
    # Centre (x, y) of each cabinet's footprint at the centre of the instance distribution.
    # Shifted towards +y: the Sawyer's arm hangs to its left and loses accuracy low down on its far right.
    cabinet_xy: ClassVar[dict[str, tuple[float, float]]] = {"green": (0.11, 0.21), "wooden": (0.11, -0.16)}
    placement_jitter_m: ClassVar[tuple[float, float]] = (0.03, 0.015)
    """Uniform jitter of each cabinet's (x, y); the cabinets stay at least 1 cm apart."""
    travel_m: ClassVar[float] = _TRAVEL * DRAWER_SCALE

    def _load_task_objects(self) -> list:
        return [self._build_cabinet(name) for name in CABINET_NAMES]

    @staticmethod
    def _build_cabinet(name: str):
        s = DRAWER_SCALE
        fixture = FixtureBuilder(f"{name}_cabinet")
        case_mesh = fixture.mesh("drawercase", "drawer/drawercase.stl", s)
        drawer_mesh = fixture.mesh("drawer", "drawer/drawer.stl", s)
        handle_mesh = fixture.mesh("drawerhandle", "drawer/drawerhandle.stl", HANDLE_SCALE)
        rgba, texture = _CABINET_MATERIALS[name]["case"]
        case_material = fixture.material("case", rgba, texture=texture)
        rgba, texture = _CABINET_MATERIALS[name]["drawer"]
        drawer_material = fixture.material("front", rgba, texture=texture)
        metal = fixture.material("metal", (0.75, 0.75, 0.75, 1.0), texture="metal1.png", shininess=0.8)
        # Fixture origin at the centre of the cabinet's footprint on the table; the inner body turns
        # Meta-World's -y (drawer fronts) towards the robot. Meta-World +x is the robot's right.
        fixture.open_body("frame", euler=(0, 0, -np.pi / 2))
        for side, sign in (("left", -1.0), ("right", 1.0)):
            x = sign * _CASE_HALF_WIDTH * s
            fixture.open_body(f"case_{side}", pos=(x, 0, _CASE_Z * s))
            fixture.visual_mesh(case_mesh, case_material)
            for pos, size in (
                ((-0.11, 0, 0), (0.008, 0.1, 0.084)),
                ((0.11, 0, 0), (0.008, 0.1, 0.084)),
                ((0, 0.092, -0.008), (0.102, 0.008, 0.076)),
                ((0, -0.008, -0.07), (0.102, 0.092, 0.014)),
                ((0, 0, 0.076), (0.102, 0.1, 0.008)),
            ):
                fixture.collision("box", np.multiply(size, s), pos=np.multiply(pos, s), mass=0.5)
            fixture.open_body(f"drawer_{side}", pos=(0, _DRAWER_Y * s, _DRAWER_Z * s))
            fixture.joint(f"slide_{side}", "slide", (0, 1, 0), (-_TRAVEL * s, 0), damping=2.0, frictionloss=0.5)
            fixture.visual_mesh(drawer_mesh, drawer_material)
            h = HANDLE_SCALE
            handle_y = _FRONT_Y * s - HANDLE_SPACER_M + _HANDLE_MESH_Y * h
            fixture.visual_mesh(handle_mesh, metal, pos=(0, handle_y, 0))
            for post_x in (-_HANDLE_HALF_LENGTH, _HANDLE_HALF_LENGTH):
                spacer_pos = (post_x * h, _FRONT_Y * s - HANDLE_SPACER_M / 2, 0)
                spacer_size = (0.006, HANDLE_SPACER_M / 2 + 0.002)
                fixture.raw(
                    f'<geom type="cylinder" size="{spacer_size[0]} {spacer_size[1]}" pos="{spacer_pos[0]} '
                    f'{spacer_pos[1]} 0" euler="1.571 0 0" material="metal" group="1" contype="0" conaffinity="0" '
                    'mass="0"/>'
                )
                fixture.collision("cylinder", spacer_size, pos=spacer_pos, euler=(1.571, 0, 0), mass=0.01)
            for pos, size in (
                ((0, -0.082, 0.008), (0.1, 0.008, 0.052)),
                ((0, 0.082, 0.008), (0.1, 0.008, 0.052)),
                ((-0.092, 0, 0.008), (0.008, 0.074, 0.052)),
                ((0.092, 0, 0.008), (0.008, 0.074, 0.052)),
                ((0, 0, -0.052), (0.1, 0.09, 0.008)),
            ):
                fixture.collision("box", np.multiply(size, s), pos=np.multiply(pos, s), mass=0.1)
            for post_x in (-_HANDLE_HALF_LENGTH, _HANDLE_HALF_LENGTH):
                fixture.collision(
                    "capsule",
                    (_HANDLE_BAR_RADIUS * h, _HANDLE_POST_HALF_LENGTH * h),
                    pos=(post_x * h, handle_y + _HANDLE_POST_Y * h, 0),
                    euler=(1.571, 0, 0),
                )
            fixture.collision(
                "capsule",
                (_HANDLE_BAR_RADIUS * h, _HANDLE_HALF_LENGTH * h),
                pos=(0, handle_y + _HANDLE_BAR_Y * h, 0),
                euler=(0, 1.571, 0),
                mass=0.1,
            )
            fixture.site(f"handle_{side}", pos=(0, handle_y + _HANDLE_BAR_Y * h, 0))
            fixture.site(f"front_{side}", pos=(0, _FRONT_Y * s, 0))
            fixture.close_body()
            fixture.close_body()
        fixture.close_body()
        return fixture.build()

    def _setup_task_references(self) -> None:
        self.cabinet_root_ids = {name: self.body_id(f"{name}_cabinet_main") for name in CABINET_NAMES}
        site_id = self.sim.model.site_name2id
        self.handle_site_ids = {}
        self.front_site_ids = {}
        for cabinet in CABINET_NAMES:
            for side in DRAWER_SIDES:
                key = drawer_key(cabinet, side)
                self.handle_site_ids[key] = site_id(f"{cabinet}_cabinet_handle_{side}")
                self.front_site_ids[key] = site_id(f"{cabinet}_cabinet_front_{side}")

    def _place_instance(self, rng: np.random.Generator) -> None:
        start = 0.0 if self.variation.params["goal"] == "open" else 1.0
        for name in CABINET_NAMES:
            x, y = self.cabinet_xy[name]
            jitter = rng.uniform(-1.0, 1.0, size=2) * self.placement_jitter_m
            self.set_fixture_pose(self.cabinet_root_ids[name], (x + jitter[0], y + jitter[1], self.table_offset[2]))
            for side in DRAWER_SIDES:
                self.set_joint_value(self.slide_joint(drawer_key(name, side)), -start * self.travel_m)

    # ------------------------------------------------------------------ geometry the success test and expert read
    @staticmethod
    def slide_joint(drawer: str) -> str:
        cabinet, side = drawer.split("_")
        return f"{cabinet}_cabinet_slide_{side}"

    @staticmethod
    def drawer_of(variation: Variation) -> str:
        return drawer_key(variation.params["cabinet"], variation.params["side"])

    def open_fraction(self, drawer: str) -> float:
        """How far the drawer is pulled out: 0 fully in, 1 fully out."""
        return -self.joint_value(self.slide_joint(drawer)) / self.travel_m

    def handle_position(self, drawer: str) -> np.ndarray:
        """Centre of the handle bar."""
        return np.array(self.sim.data.site_xpos[self.handle_site_ids[drawer]])

    def front_position(self, drawer: str) -> np.ndarray:
        """Centre of the drawer front's robot-side face, at the handle's height."""
        return np.array(self.sim.data.site_xpos[self.front_site_ids[drawer]])

    @property
    def handle_bar_radius_m(self) -> float:
        return _HANDLE_BAR_RADIUS * HANDLE_SCALE

    @property
    def handle_half_length_m(self) -> float:
        return _HANDLE_HALF_LENGTH * HANDLE_SCALE

    # ------------------------------------------------------------------ success
    def _goal_reached(self, variation: Variation) -> bool:
        asked = self.drawer_of(variation)
        opening = variation.params["goal"] == "open"
        fraction = self.open_fraction(asked)
        if opening and fraction < SUCCESS_FRACTION or not opening and fraction > 1.0 - SUCCESS_FRACTION:
            return False
        # The other drawers must still be on their starting half (closed for "open", open for "close").
        for other in DRAWER_KEYS:
            if other != asked and (self.open_fraction(other) > 0.5) == opening:
                return False
        return True
