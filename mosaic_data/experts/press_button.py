"""Press-button expert: move the closed hand above the asked button, lower the fingertips onto its cap, press it
down until it is pressed, then lift.

The fingers close at the start, while the arm moves, and the hand goes on down without a stop above the
button: a policy that sees one frame cannot tell fingers closing in the air from an arrival, and stalls there.

The hand points straight down with its wide palm spanning world x (across the machine, towards and away
from the robot), so it never reaches over the neighbouring buttons, which stand along y. The press target lies
a little below the cap's fully pressed height, so the OSC controller's tracking error (1-3 cm on the Sawyer)
still pushes the button to the end of its travel; the phase ends as soon as the button is down.
"""

from __future__ import annotations

import numpy as np

from mosaic_data.experts.base import GRIPPER_CLOSED, Phase, ScriptedExpert, TOP_DOWN
from mosaic_data.tasks.press_button import BUTTON_TRAVEL_M, PressButton

APPROACH_HEIGHT_M = 0.10
FINGERTIP_BELOW_SITE_M = 0.012
"""How far the closed fingertips reach below the grip site (both robots, about 1.2-1.4 cm)."""
PRESS_OVERSHOOT_M = 0.012
"""The press target lies this far below the cap's fully pressed height."""
DONE_FRACTION = 0.9


class PressButtonExpert(ScriptedExpert):
    env: PressButton

    max_offset_m: float = 0.07
    """The outer buttons lie up to 27 cm to the side, where the Sawyer lags its target by up to 6 cm."""

    def phases(self) -> list[Phase]:
        self.orientation = TOP_DOWN
        env = self.env
        machine = self.variation.params["machine"]
        button = self.variation.params["button"]
        index = env.button_index(self.variation)
        # The cap's top before the press, and where the grip site is when the fingertips touch it.
        top = env.button_top_position(machine, button)
        touch = top + np.array([0.0, 0.0, FINGERTIP_BELOW_SITE_M])
        above = touch + np.array([0.0, 0.0, APPROACH_HEIGHT_M])
        hover = touch + np.array([0.0, 0.0, 0.01])
        pressed = touch - np.array([0.0, 0.0, BUTTON_TRAVEL_M + PRESS_OVERSHOOT_M])

        def button_down() -> bool:
            return bool(env.press_fractions()[index] >= DONE_FRACTION)

        return [
            Phase("approach", lambda: above, GRIPPER_CLOSED, tolerance_m=0.015, max_steps=60),
            Phase("descend", lambda: hover, GRIPPER_CLOSED, tolerance_m=0.015, max_steps=40, max_step_m=0.008),
            Phase("press", lambda: pressed, GRIPPER_CLOSED, tolerance_m=0.0, done=button_down, max_steps=40, max_step_m=0.004),
            Phase("lift", lambda: above, GRIPPER_CLOSED, tolerance_m=0.02, max_steps=30, max_step_m=0.008),
        ]
