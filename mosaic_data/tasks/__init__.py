"""The MOSAIC task suite: one module per task, each a robosuite environment class on :mod:`.base`.

The simulator loads only when a task class is asked for (``TASKS``, ``get_task_class``, ``make_task_env``, the
class names): names, variations and conventions come from :mod:`.spec`, so dataset tools, command lines and
the policy read the suite's table without importing robosuite (about half a second, and its import warnings).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from mosaic_data.tasks.spec import (
    ROBOTS,
    TASK_NAMES,
    TASK_SPECS,
    VARIATIONS,
    TaskSpec,
    Variation,
    get_task_spec,
    unknown_task_error,
    validate_robot,
)

if TYPE_CHECKING:
    from mosaic_data.tasks.base import MosaicTaskEnv

CLASS_NAMES: dict[str, str] = {
    "door": "Door",
    "drawer": "Drawer",
    "press_button": "PressButton",
    "stack_block": "StackBlock",
    "basketball": "Basketball",
    "nut_assembly": "NutAssembly",
    "pick_place": "PickPlace",
}
"""Task key -> its environment class, defined in ``mosaic_data.tasks.<task key>`` (also its gymnasium name)."""


def get_task_class(task: str) -> type[MosaicTaskEnv]:
    """The robosuite environment class of ``task`` (imports the simulator)."""
    if task not in CLASS_NAMES:
        raise unknown_task_error(task)
    return getattr(importlib.import_module(f"mosaic_data.tasks.{task}"), CLASS_NAMES[task])


def __getattr__(name: str) -> Any:
    """``TASKS``, ``MosaicTaskEnv`` and the task classes, imported on first use (they load robosuite)."""
    if name == "TASKS":
        tasks = {task: get_task_class(task) for task in TASK_NAMES}
        globals()["TASKS"] = tasks
        return tasks
    if name == "MosaicTaskEnv":
        from mosaic_data.tasks.base import MosaicTaskEnv

        return MosaicTaskEnv
    for task, class_name in CLASS_NAMES.items():
        if name == class_name:
            return get_task_class(task)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def select_variations(
    task: str, variations: list[int] | None, task_option: str = "--task", variations_option: str = "--variations"
) -> dict[str, list[int]]:
    """Task -> variations for a command's task option (a task key or 'all') and variations option (None =
    every variation); ValueError with one line naming the command's own options."""
    if task == "all":
        if variations is not None:
            raise ValueError(f"{variations_option} applies to one task; drop it with {task_option} all")
        return {name: [v.index for v in table] for name, table in VARIATIONS.items()}
    if task not in VARIATIONS:
        raise unknown_task_error(task, task_option, extra_choices=("all",))
    count = len(VARIATIONS[task])
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


__all__ = [
    "ROBOTS",
    "TASKS",
    "TASK_NAMES",
    "TASK_SPECS",
    "VARIATIONS",
    "MosaicTaskEnv",
    "TaskSpec",
    "Variation",
    "get_task_class",
    "get_task_spec",
    "make_task_env",
    "select_variations",
    "validate_robot",
]
