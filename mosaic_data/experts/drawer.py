"""Drawer expert: hook the handle and pull the drawer out, or push its handle until the drawer is in.

Both goals keep the gripper closed, so the fingers form a narrow block.
Open: the hand's long side runs along the drawer front (fingers spread along world y), so the hand stays in
front of the cabinet while, from above, the closed fingers drop into the gap between the handle bar and the
drawer front; then the target runs a little ahead of the handle towards the robot until the drawer is out.
The hand centres itself between the neighbouring (closed) drawers' handles.
Close: the hand turns its long side towards the cabinet (fingers spread along world x), so it is narrow
across the row of open drawers and never touches a neighbouring drawer; from above, the fingers drop in
front of the bar (robot side), then the target runs a little ahead of the handle until the drawer is in.
Targets follow the handle's current position, so the hand moves with the drawer instead of fighting it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mosaic_data.experts.base import GRIPPER_CLOSED, Phase, ScriptedExpert, top_down
from mosaic_data.tasks.drawer import DRAWER_KEYS, SUCCESS_FRACTION, Drawer

APPROACH_HEIGHT_M = 0.10
ALIGN_DESCENT_M = 0.05
ALIGN_STEPS = 10
"""The first ``ALIGN_DESCENT_M`` of the descent are slow, over ``ALIGN_STEPS`` steps, for the arm to settle."""
FINGER_HALF_THICKNESS_M = 0.012
"""Half thickness of the closed fingers around the grip site, across their spreading direction."""
FINGER_HALF_WIDTH_M = 0.03
"""Half extent of the closed fingers around the grip site, along their spreading direction."""
HOOK_CLEARANCE_M = 0.008
"""Gap left between the bar and the fingers' robot-side face when the hook drops in (it closes when pulling)."""
PUSH_STANDOFF_M = 0.035
HOOK_TOLERANCE_M = np.array([0.008, 0.025, 0.008])
PUSH_TOLERANCE_M = np.array([0.02, 0.025, 0.015])
"""How far off its target along x, y, z the hand may be to go on. Along the bar (y) the hand has room (the
Sawyer lags on its right); the hook drops into an 8 mm gap; the pushing fingers only need to stay in front of
the bar (``PUSH_STANDOFF_M``) and below its top. Going on while the integrated tracking offset still pulls the
arm over avoids a stop that the camera can barely see."""
LEAD_M = 0.04
"""How far the target runs ahead of the handle while the drawer slides."""
HOOK_BELOW_BAR_M = 0.004
"""The hook's grip site sits a little below the bar's axis, so the fingertips reach well under it."""
PUSH_BELOW_BAR_M = 0.002
"""The pushing fingers reach below the bar's axis (so they cannot ride up over it), the hand stays above it."""
MAX_SIDE_SHIFT_M = 0.02
"""The hand engages the bar up to this far from its middle, to stay equally far from the neighbouring handles
on both sides (the hand is wider than a drawer's handle)."""
OPEN_TARGET_FRACTION = min(0.99, SUCCESS_FRACTION + 0.06)
CLOSE_TARGET_FRACTION = max(0.01, 1.0 - SUCCESS_FRACTION - 0.07)
"""The slide phase ends past these fractions of the travel (open / close), short of the end stops."""
OVERDRIVE_M = 0.005
"""The slide target stops this far beyond the drawer's end stop, so the hand arrives gently instead of
slamming the drawer into the stop (it would bounce back out of the success range)."""


class DrawerExpert(ScriptedExpert):
    env: Drawer

    def phases(self) -> list[Phase]:
        env = self.env
        drawer = env.drawer_of(self.variation)
        opening = self.variation.params["goal"] == "open"
        bar_radius = env.handle_bar_radius_m
        if opening:  # in the gap between the bar and the drawer front, then pull towards the robot (-x)
            self.orientation = top_down(0.0)  # hand's long side along the drawer front
            direction = np.array([-1.0, 0.0, 0.0])
            # Grip site when the fingers touch the bar's far side, and the clearance left when dropping in.
            contact = np.array([bar_radius + FINGER_HALF_THICKNESS_M, self._side_shift(drawer), -HOOK_BELOW_BAR_M])
            clearance = HOOK_CLEARANCE_M
            tolerance = HOOK_TOLERANCE_M
        else:  # in front of the bar, then push away from the robot (+x)
            # Hand's long side towards the cabinet; of the two equivalent yaws, the Sawyer tracks this one better.
            self.orientation = top_down(-np.pi / 2)
            direction = np.array([1.0, 0.0, 0.0])
            contact = np.array([-(bar_radius + FINGER_HALF_WIDTH_M), 0.0, -PUSH_BELOW_BAR_M])
            clearance = PUSH_STANDOFF_M
            tolerance = PUSH_TOLERANCE_M
        lift = np.array([0.0, 0.0, APPROACH_HEIGHT_M])

        def contact_point() -> np.ndarray:
            return env.handle_position(drawer) + contact

        def engage_point() -> np.ndarray:
            return contact_point() - direction * clearance

        def slide_target() -> np.ndarray:
            fraction = env.open_fraction(drawer)
            remaining = (1.0 - fraction if opening else fraction) * env.travel_m
            return contact_point() + direction * float(np.clip(remaining + OVERDRIVE_M, 0.0, LEAD_M))

        def slid_enough() -> bool:
            fraction = env.open_fraction(drawer)
            return fraction > OPEN_TARGET_FRACTION if opening else fraction < CLOSE_TARGET_FRACTION

        above = engage_point() + lift
        halfway = above - np.array([0.0, 0.0, ALIGN_DESCENT_M])

        def near(target: Callable[[], np.ndarray]) -> Callable[[], bool]:
            def check() -> bool:
                error = np.abs(env.eef_pos - target())
                return bool(np.all(error < tolerance))

            return check

        return [
            Phase("approach", lambda: above, GRIPPER_CLOSED, tolerance_m=0.0, done=self.command_arrived(lambda: above), max_steps=60, paced=True),
            # Settle on the way down: the fast approach leaves the arm (mostly the Sawyer) overshooting, and a slow
            # first half of the descent integrates that out while the hand keeps moving (a policy seeing one frame
            # cannot tell a stop to settle from an arrival).
            Phase(
                "align",
                lambda: halfway,
                GRIPPER_CLOSED,
                tolerance_m=0.008,
                done=near(lambda: halfway),
                min_steps=ALIGN_STEPS,
                max_steps=25,
                max_step_m=ALIGN_DESCENT_M / ALIGN_STEPS,
            ),
            Phase(
                "descend",
                engage_point,
                GRIPPER_CLOSED,
                tolerance_m=0.01,
                done=near(engage_point),
                max_steps=40,
                max_step_m=0.01,
            ),
            Phase(
                "slide", slide_target, GRIPPER_CLOSED, tolerance_m=0.0, done=slid_enough, max_steps=80, max_step_m=0.01
            ),
            Phase(
                "retreat",
                lambda: self._retreat_target(-direction * 0.01 + lift),
                GRIPPER_CLOSED,
                tolerance_m=0.02,
                max_steps=30,
            ),
        ]

    def _retreat_target(self, move: np.ndarray) -> np.ndarray:
        """Up and a little off the bar from where the hand let go (fixed, so that it does not chase the drawer)."""
        if self._retreat_from is None:
            self._retreat_from = self.env.eef_pos
        return self._retreat_from + move

    def reset(self) -> None:
        super().reset()
        self._retreat_from: np.ndarray | None = None

    def _side_shift(self, drawer: str) -> float:
        """Shift along the bar (world y) that centres the hand between the neighbouring handles."""
        y = self.env.handle_position(drawer)[1]
        others = np.array([self.env.handle_position(other)[1] for other in DRAWER_KEYS if other != drawer])
        left, right = others[others > y], others[others < y]
        if len(left) and len(right):
            shift = (left.min() + right.max()) / 2 - y
        else:
            shift = -MAX_SIDE_SHIFT_M if len(left) else MAX_SIDE_SHIFT_M
        return float(np.clip(shift, -MAX_SIDE_SHIFT_M, MAX_SIDE_SHIFT_M))
