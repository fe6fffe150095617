"""Nut-assembly expert: grasp the asked nut by its handle from above, carry it over the asked peg, thread it
down the peg and let go.

The fingers close across the handle (the hand turned with the nut's yaw), so the nut hangs from the closed
fingers. While carrying and lowering, the target is corrected by the nut's actual offset from the peg's axis
(the nut may turn a little in the grasp), so its hole comes down centred on the peg. It is let go once it is
well down the peg, and drops to the peg's base.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mosaic_data.experts.base import GRIPPER_CLOSED, GRIPPER_OPEN, GraspingExpert, Phase, top_down
from mosaic_data.tasks.nut_assembly import NUT_HALF_THICKNESS_M, PEG_HEIGHT_M, NutAssembly

APPROACH_HEIGHT_M = 0.10
"""Above the handle, where the fast approach ends."""
HOVER_HEIGHT_M = 0.04
"""Above the handle, where the hand settles before the slow descent."""
GRASP_OUT_M = 0.008
"""The fingers close this far out along the handle from its centre, towards its free end (the handle reaches
0.025 m out from its centre). The ring is wider (4.5 cm) than the handle (3.2 cm) and ends only 6 mm inwards of
the handle's centre; the Panda's finger pads are 16 mm wide, so pads centred on the handle's centre reach over
the ring's outer corners and the fingers stop on those corners instead of squeezing the handle's flat faces:
a grip on two edges that the nut can twist out of when the hand starts moving down."""
GRASP_ABOVE_HANDLE_M = 0.006
"""The grip site stays at least this far above the handle's centre, so the fingers overlap most of the handle's
2 cm thickness (the Panda's pads start only about 5 mm below the site) ..."""
FINGERTIP_CLEARANCE_M = 0.006
"""... and high enough that the lowest point of the fingers stays this far above the table: fingertips dragging on
the table do not close. The Sawyer's fingertips reach 1.4 cm below the site (the Panda's fingers 0.9 cm); at the
Panda's height they touched the table, stayed open for the whole closing phase and only closed as the lift began,
on the top few millimetres of the handle: a grip the nut slipped out of in a fast carry."""
CARRY_CLEARANCE_M = 0.05
"""Height of the nut's bottom above the peg's top while it is carried."""
THREADED_DEPTH_M = 0.06
"""How far below the peg's top the nut's bottom is lowered before the fingers open."""
SLOW_DOWN_M = 0.08
CARRY_STEP_M = 0.006
"""The carry slows down to this (per step) for its last ``SLOW_DOWN_M``: stopping from full speed, the arm
(mostly the Panda) overshoots and swings around the peg for a second."""
NEAR_M = 0.015
"""The fast carry ends with the nut's centre this close to the peg's axis (xy); a slow centring follows."""
CENTRED_M = 0.006
"""The nut's centre within this of the peg's axis (xy) before and while lowering it."""
STILL_M_PER_S = 0.03
"""The nut barely moving (it swings a little on the fast carry) before it is lowered."""
LIFTED_M = 0.02
"""While carried, the nut's bottom is at least this above the table and touches the fingers; else start over."""
MAX_RETRIES = 2


def _fold_yaw(yaw: float) -> float:
    """A yaw folded into [-pi/2, pi/2): the two-finger hand looks the same every half turn."""
    return (yaw + np.pi / 2) % np.pi - np.pi / 2


class NutAssemblyExpert(GraspingExpert):
    env: NutAssembly

    carrying_phases = ("carry", "come_over", "centre", "lower")
    max_retries = MAX_RETRIES

    def holding(self) -> bool:
        nut = self.variation.params["nut"]
        lifted = self.env.nut_position(nut)[2] - NUT_HALF_THICKNESS_M - self.env.table_offset[2]
        return bool(lifted > LIFTED_M and not self.env.is_released(nut))

    def finger_reach(self) -> float:
        """How far the gripper's collision geometry (fingertips) reaches beyond the grip site along the hand's
        pointing axis, from the model (a property of the gripper, whatever its pose or opening)."""
        model, data = self.env.sim.model, self.env.sim.data
        site, pointing = self.env.eef_pos, self.env.eef_rotation.apply([0.0, 0.0, 1.0])
        reach = 0.0
        for name in self.env.robot.gripper["right"].contact_geoms:
            geom = model.geom_name2id(name)
            rotation, centre = data.geom_xmat[geom].reshape(3, 3), data.geom_xpos[geom]
            if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_MESH:
                mesh = model.geom_dataid[geom]
                first, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
                points = model.mesh_vert[first : first + count] @ rotation.T + centre
                furthest = float(np.max((points - site) @ pointing))
            elif model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_BOX:
                furthest = float((centre - site) @ pointing + np.abs(rotation.T @ pointing) @ model.geom_size[geom])
            else:
                furthest = float((centre - site) @ pointing + model.geom_rbound[geom])
            reach = max(reach, furthest)
        return reach

    def phases(self) -> list[Phase]:
        env = self.env
        nut, peg = self.variation.params["nut"], self.variation.params["peg"]
        # Handle along the nut's local x: under top_down(yaw) the fingers close along the direction yaw + pi/2,
        # across the handle when yaw is the nut's yaw (mod pi).
        nut_yaw = env.nut_rotation(nut).as_euler("xyz")[2]
        self.orientation = top_down(_fold_yaw(nut_yaw))
        grasp_z = max(
            env.nut_handle_position(nut)[2] + GRASP_ABOVE_HANDLE_M,
            env.table_offset[2] + self.finger_reach() + FINGERTIP_CLEARANCE_M,
        )

        def grasp() -> np.ndarray:
            """Over the handle's grasp point now (the fingers may nudge the nut), at the grasp height."""
            outwards = env.nut_rotation(nut).apply([1.0, 0.0, 0.0])[:2]
            outwards = outwards / max(float(np.linalg.norm(outwards)), 1e-6)
            return np.append(env.nut_handle_position(nut)[:2] + GRASP_OUT_M * outwards, grasp_z)

        def over_handle(height: float):
            return lambda: grasp() + np.array([0.0, 0.0, height])

        def hold_where_started(key: str, target=None):
            """The grip site's position when the phase started (or ``target()`` then), held for the whole phase."""
            return self.frozen(key, target if target is not None else (lambda: env.eef_pos))

        axis = env.peg_position(peg)
        peg_top = axis[2] + PEG_HEIGHT_M
        carry_z = peg_top + CARRY_CLEARANCE_M + NUT_HALF_THICKNESS_M  # nut centre height while carried
        release_z = peg_top - THREADED_DEPTH_M + NUT_HALF_THICKNESS_M

        def hand_for_nut_at(nut_target: np.ndarray) -> np.ndarray:
            """Where the grip site goes so that the nut's centre reaches ``nut_target`` (its offset as it hangs now)."""
            return env.eef_pos + (nut_target - env.nut_position(nut))

        grasped_at = hold_where_started("close", grasp)

        def lifted() -> np.ndarray:
            """Straight up from the grasp until the nut's centre is at the carrying height."""
            return np.array([*grasped_at()[:2], env.eef_pos[2] + carry_z - env.nut_position(nut)[2]])

        def over_peg() -> np.ndarray:
            return hand_for_nut_at(np.array([axis[0], axis[1], carry_z]))

        def off_axis() -> float:
            return float(np.linalg.norm(env.nut_position(nut)[:2] - axis[:2]))

        def near(distance: float):
            return lambda: off_axis() < distance

        def centred() -> bool:
            return off_axis() < CENTRED_M and np.linalg.norm(env.nut_velocity(nut)) < STILL_M_PER_S

        def down_peg() -> np.ndarray:
            # Go down only while the hole is over the peg; otherwise hold the height and re-centre.
            z = release_z if off_axis() < CENTRED_M + 0.002 else env.nut_position(nut)[2]
            return hand_for_nut_at(np.array([axis[0], axis[1], z]))

        def threaded() -> bool:
            return bool(env.nut_position(nut)[2] < release_z + 0.005)

        retreat = np.array([axis[0], axis[1], peg_top + 0.08])
        return [
            *self.reach_phases(over_handle, grasp, APPROACH_HEIGHT_M, HOVER_HEIGHT_M),
            self.grasp_phase("close", grasped_at),
            Phase("lift", lifted, GRIPPER_CLOSED, tolerance_m=0.015, max_steps=40),
            Phase("carry", over_peg, GRIPPER_CLOSED, tolerance_m=0.0, done=near(SLOW_DOWN_M), max_steps=60),
            Phase("come_over", over_peg, GRIPPER_CLOSED, tolerance_m=0.0, done=near(NEAR_M), max_steps=30, max_step_m=CARRY_STEP_M),
            Phase("centre", over_peg, GRIPPER_CLOSED, tolerance_m=0.0, done=centred, min_steps=3, max_steps=40, max_step_m=0.004),
            Phase("lower", down_peg, GRIPPER_CLOSED, tolerance_m=0.0, done=threaded, max_steps=50, max_step_m=0.008),
            Phase("release", hold_where_started("release"), GRIPPER_OPEN, tolerance_m=0.0, min_steps=8, max_steps=8),
            Phase("retreat", lambda: retreat, GRIPPER_OPEN, tolerance_m=0.02, max_steps=30),
        ]
