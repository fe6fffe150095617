"""DART-style noise injection (Laskey et al. 2017, "DART: Noise Injection for Robust Imitation Learning").

While an expert episode is collected, the environment executes a perturbed copy of the expert's action and the
episode records the expert's clean action. The scripted experts are closed-loop over the simulator's poses and
keep their own commanded pose, which the noise does not touch, so their next action already corrects the
perturbation: the data then holds states off the expert's exact path, labelled with the corrective action.

Only the pose is perturbed, never the gripper: the target position by Gaussian noise of ``position_std_m`` per
axis, the target orientation by a world-frame turn whose rotation vector is Gaussian with ``rotation_std_rad``
per axis. The noise of an episode comes from its own random stream, derived from the episode's instance seed
(:meth:`ActionNoise.generator`), so an episode is the same for the same seed and noise whoever collects it.

Light on purpose (numpy only at import): the command lines parse and check the option before loading the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

DEFAULT_POSITION_STD_M = 0.005
DEFAULT_ROTATION_STD_RAD = 0.02
ROTATION_PER_POSITION = DEFAULT_ROTATION_STD_RAD / DEFAULT_POSITION_STD_M
"""Rotation std (rad) per metre of position std when only the position's is given: ``0.005`` means the defaults."""
MAX_POSITION_STD_M = 0.05
MAX_ROTATION_STD_RAD = 0.5
"""Upper bounds: beyond them the expert mostly fails; a larger value is a typo (millimetres for metres)."""
NOISE_STREAM = 2
"""Spawn key of the noise's random stream under the episode seed's ``SeedSequence``: the environment takes
children 0 (scene) and 1 (robot) of the same seed (``MosaicTaskEnv.reset_to_seed``), the noise a stream of its own."""
NOISE_RULE = (
    "executed action = expert action with N(0, position_std_m) added to x, y, z and its orientation turned by "
    "the rotation vector N(0, rotation_std_rad) per world axis, gripper untouched; the dataset records the expert "
    "action; noise from numpy default_rng(SeedSequence(episode seed, spawn_key=(2,)))"
)
ARGUMENT_EXAMPLE = "POS_STD_M[,ROT_STD_RAD] in metres and radians such as 0.005 or 0.005,0.02"


@dataclass(frozen=True)
class ActionNoise:
    """Standard deviations of the noise added to the executed (not the recorded) action."""

    position_std_m: float = DEFAULT_POSITION_STD_M
    rotation_std_rad: float = DEFAULT_ROTATION_STD_RAD

    def __post_init__(self) -> None:
        for name, value, limit in (
            ("position_std_m", self.position_std_m, MAX_POSITION_STD_M),
            ("rotation_std_rad", self.rotation_std_rad, MAX_ROTATION_STD_RAD),
        ):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or not 0.0 <= value <= limit:
                raise ValueError(f"{name} must be a number from 0 to {limit}, got {value!r}")
        object.__setattr__(self, "position_std_m", float(self.position_std_m))
        object.__setattr__(self, "rotation_std_rad", float(self.rotation_std_rad))

    @property
    def active(self) -> bool:
        """Whether it perturbs anything (all-zero noise executes the expert's actions as they are)."""
        return self.position_std_m > 0.0 or self.rotation_std_rad > 0.0

    @staticmethod
    def generator(episode_seed: int | None) -> np.random.Generator:
        """The noise's random stream of the episode with instance seed ``episode_seed`` (None: unseeded)."""
        if episode_seed is None:
            return np.random.default_rng()
        return np.random.default_rng(np.random.SeedSequence(int(episode_seed), spawn_key=(NOISE_STREAM,)))

    def perturb(self, action: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The action to execute (float64, (7,)): ``action`` with its pose perturbed, gripper as it was.

        The position stays in the action box's workspace (``mosaic_data.envs``); the rotation vector of a turned
        orientation has magnitude at most pi, so it stays in the box too. Draws 6 numbers per call whatever the
        stds, so that the stream does not depend on which of them is zero.
        """
        from scipy.spatial.transform import Rotation

        from mosaic_data.envs import WORKSPACE_HIGH, WORKSPACE_LOW

        executed = np.array(action, dtype=np.float64).reshape(-1)
        position_noise, rotation_noise = rng.standard_normal(3), rng.standard_normal(3)
        if self.position_std_m > 0.0:
            executed[:3] = np.clip(executed[:3] + self.position_std_m * position_noise, WORKSPACE_LOW, WORKSPACE_HIGH)
        if self.rotation_std_rad > 0.0:
            turn = Rotation.from_rotvec(self.rotation_std_rad * rotation_noise)
            executed[3:6] = (turn * Rotation.from_rotvec(executed[3:6])).as_rotvec()
        return executed

    def to_json(self) -> dict[str, Any]:
        return {"position_std_m": self.position_std_m, "rotation_std_rad": self.rotation_std_rad, "rule": NOISE_RULE}

    @classmethod
    def from_json(cls, content: dict[str, Any]) -> ActionNoise:
        return cls(content["position_std_m"], content["rotation_std_rad"])


def parse_action_noise(text: str) -> ActionNoise | None:
    """``"0.005"`` or ``"0.005,0.02"`` -> the noise; None when it is zero (executes the expert's actions as they are).

    Without a rotation std, it is ``ROTATION_PER_POSITION`` times the position's (``0.005`` -> 0.02 rad, ``0``
    -> no noise). Raises ValueError with a message naming the expected form.
    """
    parts = [part.strip() for part in text.split(",")]
    if len(parts) > 2 or any(part == "" for part in parts):
        raise ValueError(f"expected {ARGUMENT_EXAMPLE}, got {text!r}")
    try:
        values = [float(part) for part in parts]
    except ValueError:
        raise ValueError(f"expected {ARGUMENT_EXAMPLE}, got {text!r}") from None
    if not all(math.isfinite(value) for value in values):
        raise ValueError(f"expected {ARGUMENT_EXAMPLE}, got {text!r} (not a finite number)")
    if any(value < 0 for value in values):
        raise ValueError(f"expected {ARGUMENT_EXAMPLE}, got {text!r} (a negative std)")
    position = values[0]
    rotation = values[1] if len(values) == 2 else position * ROTATION_PER_POSITION
    if position > MAX_POSITION_STD_M:
        raise ValueError(f"the position std must be at most {MAX_POSITION_STD_M} m, got {text!r} (metres, not millimetres)")
    if rotation > MAX_ROTATION_STD_RAD:
        raise ValueError(f"the rotation std must be at most {MAX_ROTATION_STD_RAD} rad, got {text!r}")
    noise = ActionNoise(position, rotation)
    return noise if noise.active else None
