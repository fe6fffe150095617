"""Basketball: three coloured balls and four hoops around the table; drop one ball through one hoop.

Variation ``i``: ball ``i // 4`` (by colour) and hoop ``i % 4`` (by position; left = +y, the robot's left,
near = closer to the robot):

====  ======  ==========  =================================================
 i    ball    hoop        description
====  ======  ==========  =================================================
 0    orange  near left   drop the orange ball through the near left hoop
 1    orange  far left    drop the orange ball through the far left hoop
 2    orange  near right  drop the orange ball through the near right hoop
 3    orange  far right   drop the orange ball through the far right hoop
 4    blue    near left   drop the blue ball through the near left hoop
 5    blue    far left    drop the blue ball through the far left hoop
 6    blue    near right  drop the blue ball through the near right hoop
 7    blue    far right   drop the blue ball through the far right hoop
 8    green   near left   drop the green ball through the near left hoop
 9    green   far left    drop the green ball through the far left hoop
10    green   near right  drop the green ball through the near right hoop
11    green   far right   drop the green ball through the far right hoop
====  ======  ==========  =================================================

The hoops are Meta-World's basketball hoop (backboard, pole and rim meshes, with its collision geoms), two on
each side of the table with their rims facing the middle, so that the camera sees the balls and the rims
(a row of backboards across the table would hide the balls from it); their poles stand ``HOOP_SUNK_M`` deep in
holes in the table, so that the Panda reaches over the rims with its hand pointing down. Each instance jitters
every hoop by up to ``HOOP_JITTER_M``. The balls are Meta-World's basketball (its meshes scaled by ``BALL_SCALE`` so that it
passes the rim with a centimetre to spare, the outer skin recoloured), on free joints. Every instance places
the three balls at random, non-overlapping spots in the middle of the table (at least ``MIN_BALL_DISTANCE_M``
apart); which colour lies where is part of the same draw.

Success: the asked ball has passed downwards through the asked hoop's rim (its centre crossed the rim's plane
going down, inside the rim) during the episode, and no other ball-hoop pair has (another ball through that
hoop, or that ball through another hoop, is a failure). Crossings are recorded at every physics step and
cleared by ``reset``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from robosuite.models.objects import MujocoXMLObject

from mosaic_data.tasks.base import MosaicTaskEnv, Variation
from mosaic_data.tasks.fixtures import FixtureBuilder
from mosaic_data.tasks.spec import BALL_NAMES, HOOP_NAMES, TASK_SPECS

BALL_COLOURS: dict[str, tuple[float, float, float, float]] = {
    "orange": (0.95, 0.45, 0.05, 1.0),
    "blue": (0.12, 0.3, 0.95, 1.0),
    "green": (0.1, 0.72, 0.2, 1.0),
}
BALL_SCALE = 0.75
BALL_RADIUS_M = 0.03 * BALL_SCALE
"""Meta-World's ball (radius 0.03 m) scaled down: its rim's hole has a radius of about 0.034 m."""
RIM_HEIGHT_M = 0.25
"""Height of the rim's centre above the hoop's base (Meta-World's)."""
RIM_OFFSET_M = 0.083
"""Distance from the pole to the rim's centre, in front of the backboard (Meta-World's)."""
RIM_INNER_RADIUS_M = 0.034
"""Radius of the rim's hole (the rim's capsules' inner side)."""
RIM_Y_M = 0.28
"""Distance of the rims' centres from the table's middle line (the Sawyer's hand starts 0.17 m to its left)."""
HOOP_SUNK_M = 0.07
"""The hoops' poles stand in holes in the table, so that their rims are within the Panda's top-down reach."""
MIN_BALL_DISTANCE_M = 0.1
HOOP_JITTER_M = 0.015


def _build_ball(name: str, rgba) -> MujocoXMLObject:
    """Meta-World's basketball, recoloured and scaled, as a free-jointed robosuite object."""
    s = BALL_SCALE
    fixture = FixtureBuilder(name)
    outer = fixture.mesh("ball_outer", "basketball/basketballouter.stl", s)
    inner = fixture.mesh("ball_inner", "basketball/basketballinner.stl", s)
    skin = fixture.material("skin", rgba, shininess=0.5)
    seams = fixture.material("seams", (0.12, 0.12, 0.12, 1.0))
    fixture.visual_mesh(outer, skin)
    fixture.visual_mesh(inner, seams)
    # condim 6 adds rolling friction, so a ball nudged by a finger does not roll away across the table.
    fixture.raw(
        f'<geom name="ball" type="sphere" size="{BALL_RADIUS_M:g}" group="0" rgba="0.5 0.5 0.5 1" mass="0.1" '
        'friction="1 0.005 0.002" condim="6" solref="0.01 1" solimp="0.99 0.99 0.01"/>'
    )
    return fixture.build(joints=[dict(type="free", damping="0.0005")])


def _build_hoop(name: str):
    """Meta-World's hoop; fixture origin at the pole's foot, the rim in front of it along -x (towards the robot)."""
    fixture = FixtureBuilder(f"{name}_hoop")
    meshes = {m: fixture.mesh(m, f"basketball/{m}.stl") for m in ("backboard", "backboardsquareinner", "backboardsquareouter", "pole", "hoop")}
    white = fixture.material("white", (0.85, 0.85, 0.85, 1.0), shininess=0.5)
    red = fixture.material("red", (0.6, 0.0, 0.0, 1.0), shininess=0.5)
    metal = fixture.material("metal", (0.75, 0.75, 0.75, 1.0), texture="metal1.png", shininess=0.8)
    # Inner frame turns Meta-World's +y (away from its robot) into robosuite's +x.
    fixture.open_body("frame", euler=(0, 0, -np.pi / 2))
    fixture.visual_mesh(meshes["backboard"], white, pos=(0, 0, 0.29))
    fixture.visual_mesh(meshes["backboardsquareinner"], white, pos=(0, -0.002, 0.29))
    fixture.visual_mesh(meshes["backboardsquareouter"], red, pos=(0, -0.001, 0.29))
    fixture.visual_mesh(meshes["pole"], metal)
    fixture.collision("box", (0.1, 0.01, 0.07), pos=(0, 0, 0.29), mass=0.2)
    fixture.collision("cylinder", (0.007, 0.108), pos=(0, 0, 0.118), mass=0.2)
    fixture.collision("cylinder", (0.013, 0.005), pos=(0, 0, 0.005), mass=0.01)
    fixture.open_body("rim", pos=(0, -RIM_OFFSET_M, RIM_HEIGHT_M))
    fixture.visual_mesh(meshes["hoop"], red, pos=(0, 0, -0.001))
    fixture.collision("box", (0.01, 0.014, 0.004), pos=(0, 0.06, 0))
    for pos, euler in (
        ((0.031, 0.032, -0.001), (1.571, 0.785, 0)),
        ((0, 0.045, -0.001), (0, 1.57, 0)),
        ((0.044, 0, -0.001), (1.57, 0, 0)),
        ((-0.044, 0, -0.001), (1.57, 0, 0)),
        ((0, -0.045, -0.001), (0, 1.57, 0)),
        ((-0.031, 0.032, -0.001), (1.57, -0.785, 0)),
        ((-0.031, -0.032, -0.001), (1.57, 0.785, 0)),
        ((0.031, -0.032, -0.001), (1.57, -0.785, 0)),
    ):
        fixture.collision("capsule", (0.01, 0.016), pos=pos, euler=euler)
    fixture.site("rim_centre")
    fixture.close_body()
    fixture.close_body()
    return fixture.build()


class Basketball(MosaicTaskEnv):
    task_name: ClassVar[str] = "basketball"
    variations: ClassVar[tuple[Variation, ...]] = TASK_SPECS["basketball"].variations
    horizon_steps: ClassVar[int] = TASK_SPECS["basketball"].horizon_steps
    # Each hoop's pole foot (x, y) and the yaw that turns its rim (built facing -x) towards the table's middle.
    hoop_poses: ClassVar[dict[str, tuple[float, float, float]]] = {
        "near_left": (-0.25, RIM_Y_M + RIM_OFFSET_M, np.pi / 2),
        "far_left": (-0.03, RIM_Y_M + RIM_OFFSET_M, np.pi / 2),
        "near_right": (-0.25, -RIM_Y_M - RIM_OFFSET_M, -np.pi / 2),
        "far_right": (-0.03, -RIM_Y_M - RIM_OFFSET_M, -np.pi / 2),
    }
    # Region (x, y ranges) where the balls' centres are drawn, between the hoops.
    placement_x_range: ClassVar[tuple[float, float]] = (-0.2, 0.08)
    placement_y_range: ClassVar[tuple[float, float]] = (-0.13, 0.13)

    def _load_task_objects(self) -> list:
        self.balls = {name: _build_ball(f"{name}_ball", rgba) for name, rgba in BALL_COLOURS.items()}
        return [_build_hoop(name) for name in HOOP_NAMES] + list(self.balls.values())

    def _setup_task_references(self) -> None:
        self.hoop_root_ids = {name: self.body_id(f"{name}_hoop_main") for name in HOOP_NAMES}
        self.rim_site_ids = {name: self.sim.model.site_name2id(f"{name}_hoop_rim_centre") for name in HOOP_NAMES}
        self.ball_body_ids = {name: self.body_id(ball.root_body) for name, ball in self.balls.items()}
        self._through = np.zeros((len(BALL_NAMES), len(HOOP_NAMES)), dtype=bool)
        self._above_rim = np.zeros((len(BALL_NAMES), len(HOOP_NAMES)), dtype=bool)

    def _place_instance(self, rng: np.random.Generator) -> None:
        for name in HOOP_NAMES:
            x, y, yaw = self.hoop_poses[name]
            jitter = rng.uniform(-HOOP_JITTER_M, HOOP_JITTER_M, size=2)
            self.set_fixture_pose(
                self.hoop_root_ids[name], (x + jitter[0], y + jitter[1], self.table_offset[2] - HOOP_SUNK_M), yaw
            )
        positions: list[np.ndarray] = []
        while len(positions) < len(BALL_NAMES):
            candidate = np.array([rng.uniform(*self.placement_x_range), rng.uniform(*self.placement_y_range)])
            if all(np.linalg.norm(candidate - other) >= MIN_BALL_DISTANCE_M for other in positions):
                positions.append(candidate)
            elif positions and rng.uniform() < 0.05:
                positions.clear()  # a start that leaves no room: draw all spots again
        z = self.table_offset[2] + BALL_RADIUS_M
        for ball, xy in zip(self.balls.values(), positions):
            self.sim.data.set_joint_qpos(ball.joints[0], np.concatenate([xy, [z], [1.0, 0.0, 0.0, 0.0]]))
        self.sim.forward()
        self._through[:] = False
        self._above_rim[:] = self._ball_above_rims()

    # ------------------------------------------------------------------ crossing memory
    def _pre_action(self, action, policy_step=False):
        super()._pre_action(action, policy_step)
        self._record_crossings()

    def _post_action(self, action):
        self._record_crossings()
        return super()._post_action(action)

    def _ball_above_rims(self) -> np.ndarray:
        balls = np.array([self.ball_position(b) for b in BALL_NAMES])
        rims = np.array([self.rim_position(h) for h in HOOP_NAMES])
        return balls[:, None, 2] >= rims[None, :, 2]

    def _record_crossings(self) -> None:
        """A ball crossed a rim's plane downwards since the last physics step, with its centre inside the rim."""
        above = self._ball_above_rims()
        balls = np.array([self.ball_position(b) for b in BALL_NAMES])
        rims = np.array([self.rim_position(h) for h in HOOP_NAMES])
        inside = np.linalg.norm(balls[:, None, :2] - rims[None, :, :2], axis=-1) < RIM_INNER_RADIUS_M
        self._through |= self._above_rim & ~above & inside
        self._above_rim = above

    # ------------------------------------------------------------------ geometry the success test and expert read
    def ball_position(self, ball: str) -> np.ndarray:
        return np.array(self.sim.data.xpos[self.ball_body_ids[ball]])

    def ball_velocity(self, ball: str) -> np.ndarray:
        return np.array(self.sim.data.get_joint_qvel(self.balls[ball].joints[0])[:3])

    def rim_position(self, hoop: str) -> np.ndarray:
        """Centre of the hoop's rim."""
        return np.array(self.sim.data.site_xpos[self.rim_site_ids[hoop]])

    def rim_top_z(self, hoop: str) -> float:
        return float(self.rim_position(hoop)[2] + 0.01)

    def backboard_direction(self, hoop: str) -> np.ndarray:
        """Unit vector (x, y) from the rim's centre towards its backboard."""
        pole = np.array(self.sim.data.xpos[self.hoop_root_ids[hoop]])[:2]
        direction = pole - self.rim_position(hoop)[:2]
        return direction / np.linalg.norm(direction)

    def passed_through(self) -> np.ndarray:
        """(ball, hoop) pairs whose ball has passed downwards through the hoop since the last reset."""
        return self._through.copy()

    # ------------------------------------------------------------------ success
    def _goal_reached(self, variation: Variation) -> bool:
        through = self._through
        ball, hoop = BALL_NAMES.index(variation.params["ball"]), HOOP_NAMES.index(variation.params["hoop"])
        return bool(through[ball, hoop] and through.sum() == 1)
