"""Scripted experts, one per task, for both robots (see :mod:`.base`)."""

from __future__ import annotations

from mosaic_data.experts.base import Phase, ScriptedExpert
from mosaic_data.experts.basketball import BasketballExpert
from mosaic_data.experts.door import DoorExpert
from mosaic_data.experts.drawer import DrawerExpert
from mosaic_data.experts.nut_assembly import NutAssemblyExpert
from mosaic_data.experts.pick_place import PickPlaceExpert
from mosaic_data.experts.press_button import PressButtonExpert
from mosaic_data.experts.stack_block import StackBlockExpert
from mosaic_data.tasks import MosaicTaskEnv

EXPERTS: dict[str, type[ScriptedExpert]] = {
    "door": DoorExpert,
    "drawer": DrawerExpert,
    "press_button": PressButtonExpert,
    "stack_block": StackBlockExpert,
    "basketball": BasketballExpert,
    "nut_assembly": NutAssemblyExpert,
    "pick_place": PickPlaceExpert,
}


def make_expert(env, variation: int | None = None) -> ScriptedExpert:
    """The scripted expert of ``env``'s task pursuing ``variation`` (default: the env's own variation).

    ``env`` may be a gymnasium environment made with ``gymnasium.make("mosaic/...")`` or a task environment.
    Another variation's expert acts in the same scene, which is how success tests are checked for
    specificity.
    """
    task_env = getattr(env, "unwrapped", env)
    task_env = getattr(task_env, "task_env", task_env)
    if not isinstance(task_env, MosaicTaskEnv):
        raise ValueError(f"make_expert needs a mosaic environment, got {type(env).__name__}: use gymnasium.make('mosaic/...')")
    chosen = task_env.variation if variation is None else task_env.variations[task_env.validate_variation(variation)]
    return EXPERTS[task_env.task_name](task_env, chosen)


__all__ = ["EXPERTS", "Phase", "ScriptedExpert", "make_expert"]
