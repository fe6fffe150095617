"""The MOSAIC task suite: one module per task, each a robosuite environment class on :mod:`.base`."""

from __future__ import annotations

from mosaic_data.tasks.base import ROBOTS, MosaicTaskEnv, Variation, validate_robot
from mosaic_data.tasks.basketball import Basketball
from mosaic_data.tasks.door import Door
from mosaic_data.tasks.drawer import Drawer
from mosaic_data.tasks.nut_assembly import NutAssembly
from mosaic_data.tasks.pick_place import PickPlace
from mosaic_data.tasks.press_button import PressButton
from mosaic_data.tasks.stack_block import StackBlock

TASKS: dict[str, type[MosaicTaskEnv]] = {
    "door": Door,
    "drawer": Drawer,
    "press_button": PressButton,
    "stack_block": StackBlock,
    "basketball": Basketball,
    "nut_assembly": NutAssembly,
    "pick_place": PickPlace,
}
"""Task key -> environment class, in the paper's order."""


def get_task_class(task: str) -> type[MosaicTaskEnv]:
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}: choose one of {', '.join(TASKS)}")
    return TASKS[task]


def make_task_env(task: str, variation: int = 0, robot: str = "panda", **kwargs) -> MosaicTaskEnv:
    """Build the robosuite environment of ``task`` for one variation and robot."""
    task_class = get_task_class(task)
    task_class.validate_variation(variation)
    validate_robot(robot)
    return task_class(variation=variation, robot=robot, **kwargs)


__all__ = ["ROBOTS", "TASKS", "MosaicTaskEnv", "Variation", "get_task_class", "make_task_env"]
