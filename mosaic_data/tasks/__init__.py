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


def select_variations(
    task: str, variations: list[int] | None, task_option: str = "--task", variations_option: str = "--variations"
) -> dict[str, list[int]]:
    """Task -> variations for a command's task option (a task key or 'all') and variations option (None =
    every variation); ValueError with one line naming the command's own options."""
    if task == "all":
        if variations is not None:
            raise ValueError(f"{variations_option} applies to one task; drop it with {task_option} all")
        return {name: [v.index for v in task_class.variations] for name, task_class in TASKS.items()}
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r} ({task_option}): choose one of {', '.join(TASKS)} or 'all'")
    count = len(TASKS[task].variations)
    if variations is None:
        return {task: list(range(count))}
    if not variations or any(not 0 <= v < count for v in variations):
        raise ValueError(f"{task} has variations 0..{count - 1}; got {variations_option} {list(variations)} (see `mosaic-data tasks --task {task}`)")
    return {task: list(dict.fromkeys(variations))}


def make_task_env(task: str, variation: int = 0, robot: str = "panda", **kwargs) -> MosaicTaskEnv:
    """Build the robosuite environment of ``task`` for one variation and robot."""
    task_class = get_task_class(task)
    task_class.validate_variation(variation)
    validate_robot(robot)
    return task_class(variation=variation, robot=robot, **kwargs)


__all__ = ["ROBOTS", "TASKS", "MosaicTaskEnv", "Variation", "get_task_class", "make_task_env", "select_variations"]
