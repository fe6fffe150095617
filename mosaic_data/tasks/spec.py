"""The task suite as plain data: robots, shapes of actions and observations, and every task's variations.

This is the one table of the suite. The robosuite task classes (:mod:`.base` and one module per task) take
their ``variations`` and conventions from here, and code that needs only names and descriptions (dataset
tools, command lines, the policy's per-task loss weights) reads it without loading the simulator: this module
imports only the standard library (the ``mosaic_data`` package itself adds gymnasium, for its registrations).
"""

from __future__ import annotations

import difflib
import functools
import itertools
import numbers
from dataclasses import dataclass, field
from typing import Any

# Rates and sizes are the toolkit's shared conventions; imported from there and importable from here, as before.
from mosaic_data.constants import ACTION_DIM, IMAGE_HEIGHT, IMAGE_WIDTH, STATE_DIM  # noqa: F401
from mosaic_data.constants import FPS as CONTROL_FREQ_HZ  # noqa: F401

ROBOTS: dict[str, str] = {"panda": "Panda", "sawyer": "Sawyer"}
"""Robot key -> robosuite robot name. The Panda is the agent, the Sawyer the demonstrator."""

GRIPPER_OPEN = -1.0
GRIPPER_CLOSED = 1.0


@dataclass(frozen=True)
class Variation:
    """One variation of a task: its index, a description unique across the suite, and scene parameters."""

    index: int
    description: str
    params: dict[str, Any] = field(default_factory=dict)


def check_variation(task: str, count: int, variation: int) -> int:
    """``variation`` as an int if it indexes one of the ``count`` variations of ``task``, else ValueError."""
    if isinstance(variation, bool) or not isinstance(variation, numbers.Integral) or not 0 <= variation < count:
        raise ValueError(
            f"unknown variation {variation!r} for task '{task}': choose an integer in 0..{count - 1} "
            f"(`mosaic-data tasks` lists them)"
        )
    return int(variation)


def validate_robot(robot: str) -> str:
    """``robot`` if it is one of :data:`ROBOTS`, else ValueError naming the choices."""
    if robot not in ROBOTS:
        raise ValueError(f"unknown robot {robot!r}: choose one of {', '.join(ROBOTS)}")
    return robot


# -- the names a variation is made of (the task modules build their scenes from the same names) -----------

DOOR_NAMES = ("left", "right")
SWINGS = ("push", "pull")

CABINET_NAMES = ("green", "wooden")
DRAWER_SIDES = ("left", "right")
GOALS = ("open", "close")

MACHINE_NAMES = ("left", "right")
MACHINE_COLOUR_NAMES = {"left": "yellow", "right": "blue"}
BUTTON_POSITIONS = ("left", "middle", "right")
BUTTON_COLOUR_NAMES = ("red", "green", "white")

CUBE_NAMES = ("red", "green", "blue")

BALL_NAMES = ("orange", "blue", "green")
HOOP_NAMES = ("near_left", "far_left", "near_right", "far_right")

NUT_NAMES = ("blue", "red", "green")
PEG_NAMES = ("left", "middle", "right")

ITEM_NAMES = ("milk", "bread", "cereal", "can")
ITEM_LABELS = {"milk": "milk carton", "bread": "bread loaf", "cereal": "cereal box", "can": "soda can"}
BIN_NAMES = ("far_left", "mid_left", "mid_right", "far_right")
BIN_LABELS = {"far_left": "far-left", "mid_left": "middle-left", "mid_right": "middle-right", "far_right": "far-right"}


def _numbered(entries: list[tuple[str, dict[str, Any]]]) -> tuple[Variation, ...]:
    return tuple(Variation(index, description, params) for index, (description, params) in enumerate(entries))


def _door() -> tuple[Variation, ...]:
    entries = []
    for door in DOOR_NAMES:
        for swing in SWINGS:
            if swing == "push":
                description = f"push the {door} door open, away from the robot"
            else:
                description = f"pull the {door} door open, towards the robot"
            entries.append((description, {"door": door, "swing": swing}))
    return _numbered(entries)


def _drawer() -> tuple[Variation, ...]:
    return _numbered(
        [
            (f"{goal} the {side} drawer of the {cabinet} cabinet", {"cabinet": cabinet, "side": side, "goal": goal})
            for cabinet in CABINET_NAMES
            for side in DRAWER_SIDES
            for goal in GOALS
        ]
    )


def _press_button() -> tuple[Variation, ...]:
    entries = []
    for machine in MACHINE_NAMES:
        for button, (position, colour) in enumerate(zip(BUTTON_POSITIONS, BUTTON_COLOUR_NAMES, strict=True)):
            where = "in the middle of" if position == "middle" else f"on the {position} of"
            description = f"press the {colour} button {where} the {MACHINE_COLOUR_NAMES[machine]} machine"
            entries.append((description, {"machine": machine, "button": button, "colour": colour}))
    return _numbered(entries)


def _stack_block() -> tuple[Variation, ...]:
    return _numbered(
        [
            (f"stack the {picked} block on the {base} block", {"picked": picked, "base": base, "distractor": distractor})
            for picked, base, distractor in itertools.permutations(CUBE_NAMES)
        ]
    )


def _basketball() -> tuple[Variation, ...]:
    return _numbered(
        [
            (f"drop the {ball} ball through the {hoop.replace('_', ' ')} hoop", {"ball": ball, "hoop": hoop})
            for ball in BALL_NAMES
            for hoop in HOOP_NAMES
        ]
    )


def _nut_assembly() -> tuple[Variation, ...]:
    return _numbered(
        [(f"put the {nut} nut on the {peg} peg", {"nut": nut, "peg": peg}) for nut in NUT_NAMES for peg in PEG_NAMES]
    )


def _pick_place() -> tuple[Variation, ...]:
    return _numbered(
        [
            (f"put the {ITEM_LABELS[item]} in the {BIN_LABELS[bin_name]} bin", {"item": item, "bin": bin_name})
            for item in ITEM_NAMES
            for bin_name in BIN_NAMES
        ]
    )


@dataclass(frozen=True)
class TaskSpec:
    """What a task is without its scene: its key, its variations and its episode horizon (control steps).

    Carries the attributes of a task class that tables need (``variations``, ``horizon_steps``), so code that
    prints or records them takes a spec where it would otherwise import the simulator for the class.
    """

    task_name: str
    variations: tuple[Variation, ...]
    horizon_steps: int

    def validate_variation(self, variation: int) -> int:
        """``variation`` as an int if it is one of this task's, else ValueError (as the task class's)."""
        return check_variation(self.task_name, len(self.variations), variation)


TASK_SPECS: dict[str, TaskSpec] = {
    spec.task_name: spec
    for spec in (
        TaskSpec("door", _door(), 130),
        TaskSpec("drawer", _drawer(), 200),
        TaskSpec("press_button", _press_button(), 120),
        TaskSpec("stack_block", _stack_block(), 200),
        TaskSpec("basketball", _basketball(), 200),
        TaskSpec("nut_assembly", _nut_assembly(), 200),
        TaskSpec("pick_place", _pick_place(), 250),
    )
}
"""Task key -> its spec, in the paper's task order; a variation's index is its position."""

TASK_NAMES: tuple[str, ...] = tuple(TASK_SPECS)
"""Task keys in the paper's order."""

VARIATIONS: dict[str, tuple[Variation, ...]] = {name: spec.variations for name, spec in TASK_SPECS.items()}
"""Task key -> its variations."""


def unknown_task_error(task: str, option: str | None = None, extra_choices: tuple[str, ...] = ()) -> ValueError:
    """The error for a task key the suite does not have: the closest key first, since a typo ('doorr') is the usual
    cause, then every choice. ``option`` names the command's flag; ``extra_choices`` are its other accepted values
    (e.g. 'all'), suggested and listed too."""
    choices = list(TASK_NAMES) + list(extra_choices)
    where = f" ({option})" if option else ""
    close = difflib.get_close_matches(str(task), choices, n=1, cutoff=0.6)
    hint = f" did you mean {close[0]!r}?" if close else ""
    listed = ", ".join(TASK_NAMES) + "".join(f" or {choice!r}" for choice in extra_choices)
    return ValueError(f"unknown task {task!r}{where}:{hint} choose one of {listed}")


def get_task_spec(task: str) -> TaskSpec:
    """The spec of ``task``; ValueError naming the closest key and the choices for an unknown key."""
    if task not in TASK_SPECS:
        raise unknown_task_error(task)
    return TASK_SPECS[task]


@functools.cache
def task_of_variation() -> dict[str, str]:
    """Variation description (a recorded episode's LeRobot task string) -> task key, over the whole suite."""
    table = {variation.description: task for task, variations in VARIATIONS.items() for variation in variations}
    if len(table) != sum(len(v) for v in VARIATIONS.values()):
        raise AssertionError("variation descriptions must be unique across the suite")
    return table
