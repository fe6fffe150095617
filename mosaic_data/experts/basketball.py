"""Basketball expert: grasp the asked ball from above, carry it over the asked hoop's rim and drop it through.

The hand keeps its long side along the world x axis (fingers closing along x), which is parallel to every
backboard, so the hand never meets one while the ball is over a rim. While carrying, the target is corrected
by the ball's actual offset from the rim's centre (the ball may sit off-centre between the fingers), so the
ball is let go centred over the rim, a centimetre above it, and falls through.
"""

from __future__ import annotations

import numpy as np

from mosaic_data.experts.base import GRIPPER_CLOSED, GRIPPER_OPEN, GraspingExpert, Phase, top_down
from mosaic_data.tasks.basketball import BALL_RADIUS_M, Basketball

APPROACH_HEIGHT_M = 0.10
"""Above the ball, where the fast approach ends."""
HOVER_HEIGHT_M = 0.04
"""Above the ball, where the hand settles before the slow descent."""
GRASP_BELOW_CENTRE_M = 0.002
"""The grip site a little below the ball's centre, so the finger pads squeeze it about its equator."""
CARRY_CLEARANCE_M = 0.03
"""Height of the ball's bottom above the rim's top while it is carried."""
DROP_CLEARANCE_M = 0.01
"""Height of the ball's bottom above the rim's top when the fingers open."""
SLOW_DOWN_M = 0.08
CARRY_STEP_M = 0.006
"""The carry slows down to this (per step) for its last ``SLOW_DOWN_M``, so the arm does not overshoot."""
NEAR_M = 0.012
CENTRED_M = 0.004
"""The ball's centre within this of the rim's axis (xy) before it is let go."""
STILL_M_PER_S = 0.03
LIFTED_M = 0.02
"""While carried, the ball's bottom is at least this above the table and touches the fingers; else start over."""
MAX_RETRIES = 2


class BasketballExpert(GraspingExpert):
    env: Basketball
    hand_yaw: float = np.pi / 2
    """Yaw of the top-down hand: fingers closing along world x, the hand's long side parallel to the backboards."""

    carrying_phases = ("carry", "come_over", "centre", "lower")
    max_retries = MAX_RETRIES

    def holding(self) -> bool:
        ball = self.variation.params["ball"]
        lifted = self.env.ball_position(ball)[2] - BALL_RADIUS_M - self.env.table_offset[2]
        touching = self.env.check_contact(self.env.robot.gripper["right"], self.env.balls[ball])
        return bool(lifted > LIFTED_M and touching)

    def phases(self) -> list[Phase]:
        env = self.env
        ball, hoop = self.variation.params["ball"], self.variation.params["hoop"]
        # Fingers closing along world x: the hand's long side parallel to the backboards.
        self.orientation = top_down(self.hand_yaw)
        grasp_z = env.ball_position(ball)[2] - GRASP_BELOW_CENTRE_M

        def grasp() -> np.ndarray:
            """Over the ball's current centre (a finger may nudge it), at the grasp height."""
            return np.append(env.ball_position(ball)[:2], grasp_z)

        def over_ball(height: float):
            return lambda: grasp() + np.array([0.0, 0.0, height])

        def hold_where_started(key: str, target=None):
            """The grip site's position when the phase started (or ``target()`` then), held for the whole phase."""
            return self.frozen(key, target if target is not None else (lambda: env.eef_pos))

        rim = env.rim_position(hoop)
        rim_top = env.rim_top_z(hoop)
        carry_z = rim_top + CARRY_CLEARANCE_M + BALL_RADIUS_M  # ball centre height while carried
        drop_z = rim_top + DROP_CLEARANCE_M + BALL_RADIUS_M

        def hand_for_ball_at(ball_target: np.ndarray) -> np.ndarray:
            """Where the grip site goes so that the ball's centre reaches ``ball_target`` (its offset in the hand now)."""
            return env.eef_pos + (ball_target - env.ball_position(ball))

        grasped_at = hold_where_started("close", grasp)

        def lifted() -> np.ndarray:
            """Straight up from the grasp until the ball's centre is at the carrying height."""
            return np.array([*grasped_at()[:2], env.eef_pos[2] + carry_z - env.ball_position(ball)[2]])

        def over_rim() -> np.ndarray:
            return hand_for_ball_at(np.array([rim[0], rim[1], carry_z]))

        def off_axis() -> float:
            return float(np.linalg.norm(env.ball_position(ball)[:2] - rim[:2]))

        def near(distance: float):
            return lambda: off_axis() < distance

        def down_to_drop() -> np.ndarray:
            # Go down only while the ball is over the rim's hole; otherwise hold the height and re-centre.
            z = drop_z if off_axis() < CENTRED_M + 0.002 else env.ball_position(ball)[2]
            return hand_for_ball_at(np.array([rim[0], rim[1], z]))

        def at_drop_height() -> bool:
            return bool(
                env.ball_position(ball)[2] < drop_z + 0.004
                and off_axis() < CENTRED_M
                and np.linalg.norm(env.ball_velocity(ball)) < STILL_M_PER_S
            )

        retreat = np.array([rim[0], rim[1], carry_z + 0.06])
        return [
            *self.reach_phases(over_ball, grasp, APPROACH_HEIGHT_M, HOVER_HEIGHT_M),
            self.grasp_phase("close", grasped_at),
            Phase("lift", lifted, GRIPPER_CLOSED, tolerance_m=0.015, max_steps=40),
            Phase("carry", over_rim, GRIPPER_CLOSED, tolerance_m=0.0, done=near(SLOW_DOWN_M), max_steps=60),
            Phase("come_over", over_rim, GRIPPER_CLOSED, tolerance_m=0.0, done=near(NEAR_M), max_steps=30, max_step_m=CARRY_STEP_M),
            Phase("lower", down_to_drop, GRIPPER_CLOSED, tolerance_m=0.0, done=at_drop_height, max_steps=40, max_step_m=0.004),
            Phase("release", hold_where_started("release"), GRIPPER_OPEN, tolerance_m=0.0, min_steps=8, max_steps=8),
            Phase("retreat", lambda: retreat, GRIPPER_OPEN, tolerance_m=0.02, max_steps=30),
        ]
