"""Nut-assembly expert: grasp the asked nut by its handle from above, carry it over the asked peg, thread it
down the peg and let go.

The fingers close across the handle (the hand turned with the nut's yaw), so the nut hangs from the closed
fingers. While carrying and lowering, the target is corrected by the nut's actual offset from the peg's axis
(the nut may turn a little in the grasp), so its hole comes down centred on the peg. It is let go once it is
well down the peg, and drops to the peg's base.
"""

from __future__ import annotations

import numpy as np

from mosaic_data.experts.base import GRIPPER_CLOSED, GRIPPER_OPEN, Phase, ScriptedExpert, top_down
from mosaic_data.tasks.nut_assembly import NUT_HALF_THICKNESS_M, PEG_HEIGHT_M, NutAssembly

APPROACH_HEIGHT_M = 0.10
"""Above the handle before descending to it."""
GRASP_BELOW_HANDLE_M = 0.002
"""The grip site goes this far below the handle's centre, so the finger pads cover it."""
CARRY_CLEARANCE_M = 0.05
"""Height of the nut's bottom above the peg's top while it is carried."""
THREADED_DEPTH_M = 0.06
"""How far below the peg's top the nut's bottom is lowered before the fingers open."""
CENTRED_M = 0.006
"""The nut's centre within this of the peg's axis (xy) before lowering it."""


def _fold_yaw(yaw: float) -> float:
    """A yaw folded into [-pi/2, pi/2): the two-finger hand looks the same every half turn."""
    return (yaw + np.pi / 2) % np.pi - np.pi / 2


class NutAssemblyExpert(ScriptedExpert):
    env: NutAssembly

    def phases(self) -> list[Phase]:
        env = self.env
        nut, peg = self.variation.params["nut"], self.variation.params["peg"]
        # Handle along the nut's local x: under top_down(yaw) the fingers close along the direction yaw + pi/2,
        # across the handle when yaw is the nut's yaw (mod pi).
        nut_yaw = env.nut_rotation(nut).as_euler("xyz")[2]
        self.orientation = top_down(_fold_yaw(nut_yaw))
        handle = env.nut_handle_position(nut)
        grasp = handle - np.array([0.0, 0.0, GRASP_BELOW_HANDLE_M])
        above = grasp + np.array([0.0, 0.0, APPROACH_HEIGHT_M])
        axis = env.peg_position(peg)
        peg_top = axis[2] + PEG_HEIGHT_M
        carry_z = peg_top + CARRY_CLEARANCE_M + NUT_HALF_THICKNESS_M  # nut centre height while carried
        release_z = peg_top - THREADED_DEPTH_M + NUT_HALF_THICKNESS_M

        def hand_for_nut_at(nut_target: np.ndarray) -> np.ndarray:
            """Where the grip site goes so that the nut's centre reaches ``nut_target`` (its offset as it hangs now)."""
            return env.eef_pos + (nut_target - env.nut_position(nut))

        def lifted() -> np.ndarray:
            target = env.eef_pos.copy()
            target[2] += carry_z - env.nut_position(nut)[2]
            return np.array([grasp[0], grasp[1], target[2]])

        def over_peg() -> np.ndarray:
            return hand_for_nut_at(np.array([axis[0], axis[1], carry_z]))

        def centred() -> bool:
            return bool(np.linalg.norm(env.nut_position(nut)[:2] - axis[:2]) < CENTRED_M)

        def down_peg() -> np.ndarray:
            return hand_for_nut_at(np.array([axis[0], axis[1], release_z]))

        def threaded() -> bool:
            return bool(env.nut_position(nut)[2] < release_z + 0.005)

        retreat = np.array([axis[0], axis[1], peg_top + 0.08])
        return [
            Phase("approach", lambda: above, GRIPPER_OPEN, tolerance_m=0.02, max_steps=60),
            Phase("align", lambda: above, GRIPPER_OPEN, tolerance_m=0.008, min_steps=5, max_steps=25, max_step_m=0.005),
            Phase("descend", lambda: grasp, GRIPPER_OPEN, tolerance_m=0.008, max_steps=40, max_step_m=0.01),
            Phase("close", lambda: grasp, GRIPPER_CLOSED, tolerance_m=0.0, min_steps=10, max_steps=10),
            Phase("lift", lifted, GRIPPER_CLOSED, tolerance_m=0.015, max_steps=40, max_step_m=0.012),
            Phase("carry", over_peg, GRIPPER_CLOSED, tolerance_m=0.0, done=centred, min_steps=5, max_steps=70),
            Phase("lower", down_peg, GRIPPER_CLOSED, tolerance_m=0.0, done=threaded, max_steps=40, max_step_m=0.008),
            Phase("release", down_peg, GRIPPER_OPEN, tolerance_m=0.0, min_steps=8, max_steps=8),
            Phase("retreat", lambda: retreat, GRIPPER_OPEN, tolerance_m=0.02, max_steps=30),
        ]
