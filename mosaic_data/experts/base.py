"""Scripted experts: state machines over ground-truth simulator poses, acting in the shared action space.

An expert sees the true poses of the task's fixtures and objects and emits absolute world-frame end-effector
targets (see :mod:`mosaic_data.tasks.base`). It never teleports: every action moves the commanded position at
most ``max_step_m`` from the previous one and turns it at most ``max_turn_rad``, so recorded motion looks
like a careful operator's at 20 Hz. Both robots use the same script; only their reach differs.

A task's expert is a list of :class:`Phase` objects; each phase names a target pose (a function of the
simulator state), a gripper command and when it is done. The expert advances through the phases in order.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from mosaic_data.tasks.base import GRIPPER_CLOSED, GRIPPER_DOWN, GRIPPER_OPEN, MosaicTaskEnv, Variation, action_rotation

TOP_DOWN = GRIPPER_DOWN
"""Gripper pointing straight down, the orientation both robots start near."""


def top_down(yaw_rad: float = 0.0) -> Rotation:
    """Top-down gripper orientation turned by ``yaw_rad`` about the world z axis."""
    return Rotation.from_euler("z", yaw_rad) * TOP_DOWN


@dataclass
class Phase:
    """One step of a scripted motion.

    Attributes:
        name: shown in debugging output and expert statistics.
        target: returns the world position (3,) the grip site should go to, from the current env state.
        gripper: ``GRIPPER_OPEN`` or ``GRIPPER_CLOSED`` during this phase.
        tolerance_m: the phase is done when the grip site is within this distance of the target ...
        done: ... or, if given, when this predicate of the env is true (checked in addition to reaching).
        min_steps / max_steps: bounds on the phase's duration in control steps (``max_steps`` gives up).
        orientation: target orientation; defaults to the expert's ``orientation``.
        max_step_m: overrides the expert's speed limit for this phase (slow, careful moves).
        paced: slow the move so that the hand arrives as its turn ends, instead of arriving first and waiting
            for the wrist (a hold that a policy, seeing one frame, cannot tell from arriving).
    """

    name: str
    target: Callable[[], np.ndarray]
    gripper: float = GRIPPER_OPEN
    tolerance_m: float = 0.01
    done: Callable[[], bool] | None = None
    min_steps: int = 0
    max_steps: int = 80
    orientation: Rotation | None = None
    max_step_m: float | None = None
    paced: bool = False


class ScriptedExpert:
    """Base class: runs the task's phases. Subclasses implement :meth:`phases` for their variation."""

    max_step_m: float = 0.015
    """Largest move of the commanded position in one 50 ms control step (0.3 m/s)."""
    max_turn_rad: float = 0.08
    max_lead_m: float = 0.06
    """The commanded position never runs further than this ahead of the actual grip site."""
    integral_gain: float = 0.15
    max_offset_m: float = 0.04
    """The OSC controller leaves a steady-state error of 1-3 cm on the Sawyer (torque limits, joint friction);
    the expert integrates the tracking error into an offset on the sent target, like an operator would."""

    def __init__(self, env: MosaicTaskEnv, variation: Variation) -> None:
        self.env = env
        self.variation = variation
        self.orientation = TOP_DOWN
        self.reset()

    # ------------------------------------------------------------------ API
    def reset(self) -> None:
        """Forget progress; call after every ``env.reset``."""
        self._phases: list[Phase] | None = None
        self._phase_index = 0
        self._phase_steps = 0
        self._command_pos: np.ndarray | None = None
        self._command_rot: Rotation | None = None
        self._offset = np.zeros(3)
        self._frozen_targets: dict[str, np.ndarray] = {}
        self.retries = 0
        self.acting_phase: str | None = None  # the phase that chose the last action (traces show it)

    def start_over(self) -> None:
        """Restart the script from its first phase (after a failed grasp), keeping the tracking offset."""
        retries, offset = self.retries, self._offset
        self.reset()
        self.retries, self._offset = retries + 1, offset

    def frozen(self, key: str, point: Callable[[], np.ndarray]) -> Callable[[], np.ndarray]:
        """A phase target fixed at ``point()`` the first time it is asked for, until the next (re)start.

        For moves relative to an object the hand itself displaces: the hand must not chase it.
        """

        def target() -> np.ndarray:
            if key not in self._frozen_targets:
                self._frozen_targets[key] = np.asarray(point(), dtype=float)
            return self._frozen_targets[key]

        return target

    def command_arrived(
        self, target: Callable[[], np.ndarray], tolerance_m: float = 0.005, arm_within_m: float | None = None
    ) -> Callable[[], bool]:
        """A ``done`` predicate: the commanded pose is at ``target()`` and fully turned (and, with
        ``arm_within_m``, the arm's grip site is that close to it).

        Ends a move as soon as the command arrives (or the arm is close enough), so that the next phase moves the
        command on while the arm catches up, instead of holding the command still until the arm is there."""

        def arrived() -> bool:
            if self._command_pos is None or self._command_rot is None:
                return False
            goal = target()
            turned = (self._command_rot.inv() * self.orientation).magnitude() < 1e-3
            if not (turned and np.linalg.norm(self._command_pos - goal) < tolerance_m):
                return False
            return arm_within_m is None or bool(np.linalg.norm(self.env.eef_pos - goal) < arm_within_m)

        return arrived

    @property
    def phase_name(self) -> str:
        if self._phases is None:
            return "start"
        return self._phases[min(self._phase_index, len(self._phases) - 1)].name

    @property
    def finished(self) -> bool:
        return self._phases is not None and self._phase_index >= len(self._phases)

    def act(self, obs=None, env=None) -> np.ndarray:
        """Next action (7,) for the current simulator state; ``obs`` and ``env`` are accepted for API symmetry."""
        if self._phases is None:
            self._phases = self.phases()
            self._command_pos = self.env.eef_pos
            self._command_rot = self.env.eef_rotation
        phase = self._phases[min(self._phase_index, len(self._phases) - 1)]
        target = np.asarray(phase.target(), dtype=float)
        orientation = phase.orientation or self.orientation
        max_step = self.max_step_m if phase.max_step_m is None else phase.max_step_m
        if phase.paced:
            max_step = self._paced_step(target, orientation, max_step)
        action = self._step_towards(target, orientation, max_step, phase.gripper)
        self.acting_phase = phase.name
        self._advance(phase, target)
        return action

    # ------------------------------------------------------------------ subclass hook
    def phases(self) -> list[Phase]:
        raise NotImplementedError

    # ------------------------------------------------------------------ internals
    def _paced_step(self, target: np.ndarray, orientation: Rotation, max_step: float) -> float:
        """The position step that makes the commanded position reach ``target`` as the commanded turn ends."""
        turn_steps = np.ceil((self._command_rot.inv() * orientation).magnitude() / self.max_turn_rad)
        distance = float(np.linalg.norm(target - self._command_pos))
        if turn_steps <= 0 or distance / max_step >= turn_steps:
            return max_step
        return distance / turn_steps

    def _step_towards(self, target: np.ndarray, orientation: Rotation, max_step: float, gripper: float) -> np.ndarray:
        delta = target - self._command_pos
        distance = np.linalg.norm(delta)
        if distance > max_step:
            delta = delta * (max_step / distance)
        proposal = self._command_pos + delta
        actual = self.env.eef_pos
        lead = proposal - actual
        if np.linalg.norm(lead) > self.max_lead_m:
            proposal = actual + lead * (self.max_lead_m / np.linalg.norm(lead))
        self._command_pos = proposal
        self._offset = np.clip(
            self._offset + self.integral_gain * (self._command_pos - actual), -self.max_offset_m, self.max_offset_m
        )
        self._command_rot = _turn_towards(self._command_rot, orientation, self.max_turn_rad)
        sent_pos = self._command_pos + self._offset
        return np.concatenate([sent_pos, action_rotation(self._command_rot), [gripper]]).astype(np.float32)

    def _advance(self, phase: Phase, target: np.ndarray) -> None:
        if self._phase_index >= len(self._phases):
            return
        self._phase_steps += 1
        reached = np.linalg.norm(self.env.eef_pos - target) < phase.tolerance_m
        if phase.done is not None:
            reached = reached or phase.done()
        if (reached and self._phase_steps >= phase.min_steps) or self._phase_steps >= phase.max_steps:
            self._phase_index += 1
            self._phase_steps = 0


FINGERS_CLOSING_M = 0.15
"""The fingers count as closed on an object once their opening (0..1) fell this much since the grasp began ..."""
FINGERS_STILL = 0.01
"""... and changed less than this in the last control step."""
GRASP_MIN_STEPS, GRASP_MAX_STEPS = 3, 14
ALIGNED_M = 0.01
AT_GRASP_M = 0.006
"""The hand goes on down once the arm is this close to the point over the object, and starts closing once it is
this close to the grasp point (the command is already there)."""


class GraspingExpert(ScriptedExpert):
    """An expert that carries an object: if the object is not in the hand during a carrying phase, start over."""

    carrying_phases: tuple[str, ...] = ("carry",)
    max_retries: int = 2

    def reach_phases(
        self,
        over: Callable[[float], Callable[[], np.ndarray]],
        grasp: Callable[[], np.ndarray],
        approach_height_m: float,
        hover_height_m: float,
    ) -> list[Phase]:
        """Approach (paced) to ``over(approach_height_m)``, align at ``over(hover_height_m)``, descend to ``grasp``.

        Each ends when its command arrives (align and descend: once the arm is within ``ALIGNED_M`` and
        ``AT_GRASP_M`` too), so the hand keeps moving; the slow align and descent keep a fast arm from overshooting
        down onto the object. ``over(height)`` is the target above the object at that height."""
        approach, hover = over(approach_height_m), over(hover_height_m)
        return [
            Phase(
                "approach", approach, GRIPPER_OPEN, tolerance_m=0.0, done=self.command_arrived(approach), max_steps=60,
                paced=True,
            ),
            Phase(
                "align", hover, GRIPPER_OPEN, tolerance_m=0.0, done=self.command_arrived(hover, arm_within_m=ALIGNED_M),
                max_steps=30, max_step_m=0.006,
            ),
            Phase(
                "descend", grasp, GRIPPER_OPEN, tolerance_m=0.0, done=self.command_arrived(grasp, arm_within_m=AT_GRASP_M),
                max_steps=30, max_step_m=0.005,
            ),
        ]

    def grasp_phase(self, name: str, target: Callable[[], np.ndarray], **options) -> Phase:
        """Close the fingers at ``target`` and end as soon as they have closed on the object: the hand holds
        still only as long as the fingers need (a policy seeing one frame cannot tell how far they are)."""
        openings: list[float] = []

        def closed_on_object() -> bool:
            opening = float(self.env.robot_state()[-1])
            openings.append(opening)
            return len(openings) > 1 and openings[0] - opening > FINGERS_CLOSING_M and abs(openings[-2] - opening) < FINGERS_STILL

        return Phase(
            name, target, GRIPPER_CLOSED, tolerance_m=0.0, done=closed_on_object, min_steps=GRASP_MIN_STEPS,
            max_steps=GRASP_MAX_STEPS, **options,
        )

    def act(self, obs=None, env=None) -> np.ndarray:
        if self.phase_name in self.carrying_phases and not self.holding() and self.retries < self.max_retries:
            self.start_over()
        return super().act(obs, env)

    def holding(self) -> bool:
        """True while the carried object is lifted and in contact with the gripper."""
        raise NotImplementedError


def _turn_towards(current: Rotation, goal: Rotation, max_turn: float) -> Rotation:
    angle = (current.inv() * goal).magnitude()
    if angle <= max_turn:
        return goal
    return Slerp([0.0, 1.0], Rotation.concatenate([current, goal]))(max_turn / angle)


__all__ = ["GRIPPER_CLOSED", "GRIPPER_OPEN", "GraspingExpert", "Phase", "ScriptedExpert", "TOP_DOWN", "top_down"]
