"""Press button: two button machines side by side on the table; press one of their six buttons.

Variation ``i``: machine ``i // 3`` and button ``i % 3``. Directions are the robot's (left = +y):

====  =================  ======================  ==========================================================
 i    machine            button                  description
====  =================  ======================  ==========================================================
 0    yellow (left)      left, red               press the red button on the left of the yellow machine
 1    yellow (left)      middle, green           press the green button in the middle of the yellow machine
 2    yellow (left)      right, white            press the white button on the right of the yellow machine
 3    blue (right)       left, red               press the red button on the left of the blue machine
 4    blue (right)       middle, green           press the green button in the middle of the blue machine
 5    blue (right)       right, white            press the white button on the right of the blue machine
====  =================  ======================  ==========================================================

Each machine is a housing with three buttons in a row along y, facing up. A button is Meta-World's stop
button (cap, rod and rim meshes, scaled by ``BUTTON_SCALE``) set in Meta-World's face plate, on its own
spring-loaded slide joint like Meta-World's: it travels ``BUTTON_TRAVEL_M`` down and its preloaded spring
(``stiffness`` + ``springref``) pushes it back up when let go. Next to every button, on the side away from the
robot (facing the camera), a lamp in the button's colour lights up once the button has been pressed and
stays lit for the rest of the episode, like a lift's call button, so a video shows which button was pressed
even after the hand has let go.

Success: the asked button has been pressed down at least ``PRESSED_FRACTION`` of its travel during the
episode, and no other button has (pressing a wrong button first, or two at once, never counts). The memory of
which buttons were pressed is updated at every physics step and cleared by ``reset``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from mosaic_data.tasks.base import MosaicTaskEnv, Variation
from mosaic_data.tasks.fixtures import FixtureBuilder
from mosaic_data.tasks.spec import MACHINE_NAMES, TASK_SPECS

MACHINE_COLOURS = {"left": (0.85, 0.66, 0.12, 1.0), "right": (0.2, 0.36, 0.78, 1.0)}
BUTTON_COLOURS = ((0.8, 0.05, 0.05, 1.0), (0.05, 0.65, 0.12, 1.0), (0.9, 0.9, 0.9, 1.0))
LAMP_OFF_RGBA = (0.12, 0.12, 0.12, 1.0)
LAMP_ON_BRIGHTNESS = 1.25

BUTTON_SCALE = 0.6
"""Meta-World's stop button scaled so that three fit on one machine: cap radius 2.6 cm."""
BUTTON_SPACING_M = 0.085
"""Distance between neighbouring buttons along y."""
BUTTON_TRAVEL_M = 0.02
PRESSED_FRACTION = 0.7

# Machine geometry in the machine's frame (origin at the table top under the middle button, -x faces the robot).
HOUSING_HALF_SIZE = (0.08, 0.13, 0.035)
PLATE_SCALE = 0.35
_PLATE_HALF_THICKNESS = 0.03 * PLATE_SCALE
PANEL_TOP_Z = 2 * HOUSING_HALF_SIZE[2] + _PLATE_HALF_THICKNESS
"""Height of the face plates' top, where each button's slide joint sits, above the table."""
_CAP_GAP_M = 0.006
"""Gap left between the cap and the face plate when the button is fully down."""
_CAP_BOTTOM_Z = BUTTON_TRAVEL_M + _CAP_GAP_M
"""Cap bottom above the joint frame when the button is up."""
_CAP_HEIGHT = 0.036 * BUTTON_SCALE
_CAP_RADIUS = 0.0425 * BUTTON_SCALE
CAP_TOP_Z = PANEL_TOP_Z + _CAP_BOTTOM_Z + _CAP_HEIGHT
"""Height of an unpressed cap's top above the table."""
LAMP_X = 0.06
LAMP_HALF_SIZE = (0.016, 0.022, 0.012)
"""A flat dome on the housing's top, between the face plate and the edge that faces the camera."""

SPRING_STIFFNESS = 30.0
SPRING_REF_M = -0.05
"""The spring's rest position lies 5 cm above the top of the travel: 1.5 N hold the button up, 2.1 N at the
bottom of the travel."""


class PressButton(MosaicTaskEnv):
    task_name: ClassVar[str] = "press_button"
    variations: ClassVar[tuple[Variation, ...]] = TASK_SPECS["press_button"].variations
    horizon_steps: ClassVar[int] = TASK_SPECS["press_button"].horizon_steps
    # Where each machine's middle button stands (x, y) at the centre of the instance distribution.
    machine_xy: ClassVar[dict[str, tuple[float, float]]] = {"left": (-0.02, 0.16), "right": (-0.02, -0.16)}
    placement_jitter_m: ClassVar[float] = 0.02

    def _load_task_objects(self) -> list:
        return [self._build_machine(name) for name in MACHINE_NAMES]

    @staticmethod
    def _build_machine(name: str):
        fixture = FixtureBuilder(f"{name}_machine")
        s = BUTTON_SCALE
        cap_mesh = fixture.mesh("stopbutton", "buttonbox/stopbutton.stl", s)
        rod_mesh = fixture.mesh("stopbuttonrod", "buttonbox/stopbuttonrod.stl", s)
        rim_mesh = fixture.mesh("stopbuttonrim", "buttonbox/stopbuttonrim.stl", s)
        plate_mesh = fixture.mesh("stoptop", "buttonbox/stoptop.stl", PLATE_SCALE)
        body = fixture.material("body", MACHINE_COLOURS[name], texture="metal2.png")
        black = fixture.material("black", (0.13, 0.13, 0.13, 1.0), shininess=0.8)
        metal = fixture.material("metal", (0.8, 0.8, 0.8, 1.0), texture="metal1.png", shininess=0.8)
        hx, hy, hz = HOUSING_HALF_SIZE
        fixture.solid_box((hx, hy, hz), body, pos=(0, 0, hz), mass=3.0)
        for index, colour in enumerate(BUTTON_COLOURS):
            y = (1 - index) * BUTTON_SPACING_M  # button 0 on the robot's left (+y)
            cap = fixture.material(f"cap{index}", colour, shininess=0.9)
            # Meta-World's face plate lies in its x-z plane: turn its thickness (y) to vertical.
            fixture.visual_mesh(plate_mesh, black, pos=(0, y, 2 * hz), euler=(np.pi / 2, 0, 0))
            fixture.visual_mesh(rim_mesh, metal, pos=(0, y, PANEL_TOP_Z))
            fixture.raw(
                f'<geom name="lamp{index}" type="ellipsoid" size="{" ".join(map(str, LAMP_HALF_SIZE))}" '
                f'pos="{LAMP_X} {y} {2 * hz}" rgba="{" ".join(map(str, LAMP_OFF_RGBA))}" '
                'group="1" contype="0" conaffinity="0" mass="0"/>'
            )
            fixture.open_body(f"button{index}", pos=(0, y, PANEL_TOP_Z))
            fixture.raw('<inertial pos="0 0 0.02" mass="0.02" diaginertia="1e-5 1e-5 1e-5"/>')
            fixture.joint(
                f"button{index}",
                "slide",
                (0, 0, -1),
                (0, BUTTON_TRAVEL_M),
                damping=1.0,
                stiffness=SPRING_STIFFNESS,
                springref=SPRING_REF_M,
                solreflimit="0.004 1",
            )
            # The meshes' own axis is +z (Meta-World turns them to face -y); the cap's dome points up.
            fixture.visual_mesh(cap_mesh, cap, pos=(0, 0, _CAP_BOTTOM_Z - 0.0008 * s))
            fixture.visual_mesh(rod_mesh, black, pos=(0, 0, _CAP_BOTTOM_Z - 0.0396 * s))
            fixture.collision(
                "cylinder", (_CAP_RADIUS, _CAP_HEIGHT / 2), pos=(0, 0, _CAP_BOTTOM_Z + _CAP_HEIGHT / 2), mass=0.0
            )
            fixture.site(f"button{index}_top", pos=(0, 0, _CAP_BOTTOM_Z + _CAP_HEIGHT))
            fixture.close_body()
        return fixture.build()

    def _setup_task_references(self) -> None:
        self.machine_root_ids = {name: self.body_id(f"{name}_machine_main") for name in MACHINE_NAMES}
        self.button_joints = [self.button_joint(m, b) for m in MACHINE_NAMES for b in range(len(BUTTON_COLOURS))]
        self._button_qpos_addresses = np.array([self.joint_qpos_address(j) for j in self.button_joints])
        self._lamp_geom_ids = [
            self.sim.model.geom_name2id(f"{m}_machine_lamp{b}") for m in MACHINE_NAMES for b in range(len(BUTTON_COLOURS))
        ]
        self._pressed_ever = np.zeros(len(self.button_joints), dtype=bool)

    def _place_instance(self, rng: np.random.Generator) -> None:
        for name in MACHINE_NAMES:
            x, y = self.machine_xy[name]
            jitter = rng.uniform(-self.placement_jitter_m, self.placement_jitter_m, size=2)
            self.set_fixture_pose(self.machine_root_ids[name], (x + jitter[0], y + jitter[1], self.table_offset[2]))
        for joint in self.button_joints:
            self.set_joint_value(joint, 0.0)
        self._pressed_ever[:] = False
        self._update_lamps()

    # ------------------------------------------------------------------ press memory and lamps
    def _pre_action(self, action, policy_step=False):
        super()._pre_action(action, policy_step)
        self._record_presses()

    def _post_action(self, action):
        self._record_presses()
        return super()._post_action(action)

    def _record_presses(self) -> None:
        pressed = self.pressed_now()
        if np.any(pressed & ~self._pressed_ever):
            self._pressed_ever |= pressed
            self._update_lamps()

    def _update_lamps(self) -> None:
        for index, geom_id in enumerate(self._lamp_geom_ids):
            colour = np.array(BUTTON_COLOURS[index % len(BUTTON_COLOURS)])
            on = np.clip(colour * LAMP_ON_BRIGHTNESS, 0.0, 1.0)
            on[3] = 1.0
            self.sim.model.geom_rgba[geom_id] = on if self._pressed_ever[index] else LAMP_OFF_RGBA

    # ------------------------------------------------------------------ geometry the success test and expert read
    @staticmethod
    def button_joint(machine: str, button: int) -> str:
        return f"{machine}_machine_button{button}"

    @staticmethod
    def button_index(variation: Variation) -> int:
        """Index of the variation's button in :attr:`button_joints` (equal to the variation index)."""
        return MACHINE_NAMES.index(variation.params["machine"]) * len(BUTTON_COLOURS) + variation.params["button"]

    def press_fractions(self) -> np.ndarray:
        """How far each button is pressed now, as a fraction of its travel (0 up ... 1 fully down)."""
        return self.sim.data.qpos[self._button_qpos_addresses] / BUTTON_TRAVEL_M

    def pressed_now(self) -> np.ndarray:
        return self.press_fractions() >= PRESSED_FRACTION

    def pressed_ever(self) -> np.ndarray:
        """Which buttons have been pressed since the last reset (including now)."""
        return self._pressed_ever | self.pressed_now()

    def button_top_position(self, machine: str, button: int) -> np.ndarray:
        """World position of the centre of the button cap's top (moves down as it is pressed)."""
        site_id = self.sim.model.site_name2id(f"{machine}_machine_button{button}_top")
        return np.array(self.sim.data.site_xpos[site_id])

    # ------------------------------------------------------------------ success
    def _goal_reached(self, variation: Variation) -> bool:
        pressed = self.pressed_ever()
        target = self.button_index(variation)
        return bool(pressed[target] and pressed.sum() == 1)
