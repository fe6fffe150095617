"""Sizes of an experiment: how much data, how long to train, how much to evaluate.

``paper`` is the paper's protocol; ``cpu`` scales it down to finish on a 2-core machine in hours; ``smoke`` runs a
whole recipe end to end in minutes (nothing is learned: it checks the plumbing, as CI does). Any field can be
overridden on the command line (``--set steps=200``), and the overrides are recorded with the results.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from mosaic_data.constants import POLICY_TYPES, VISION_BACKBONES
from mosaic_data.tasks.spec import TASK_NAMES


class ExperimentError(ValueError):
    """Bad experiment input (recipe, preset, task, override, output folder): the message names the fix."""


@dataclass(frozen=True)
class ExperimentPreset:
    """Data, training and evaluation budgets shared by every recipe."""

    image_size: str = "100x180"
    episodes: int = 100  # collected per variation and robot
    steps: int = 40_000  # training steps of a model trained from scratch
    batch_size: int = 30
    train_obs_frames: int = 7
    vision_backbone: str = "resnet18"  # --policy.vision_backbone: the paper's ResNet-18, or "conv" (small, for CPU)
    save_every: int = 10_000
    eval_checkpoints: int = 3  # the last K saved checkpoints of each run are evaluated
    eval_episodes: int = 10  # per variation and checkpoint
    eval_max_steps: int = 0  # cap on an evaluation episode (0: the task's horizon)
    seeds: int = 3  # training seeds per cell
    methods: tuple[str, ...] = tuple(POLICY_TYPES)  # Table I's columns, in order
    single_task_tasks: tuple[str, ...] = TASK_NAMES
    multi_task_tasks: tuple[str, ...] = TASK_NAMES
    novel_task_pool: tuple[str, ...] = TASK_NAMES  # a novel-task model trains on this pool minus the held-out task
    novel_task_tasks: tuple[str, ...] = TASK_NAMES  # held-out tasks
    fine_tune_tasks: tuple[str, ...] = TASK_NAMES
    fine_tune_methods: tuple[str, ...] = ("mosaic",)
    fine_tune_fractions: tuple[int, ...] = (25, 50, 75, 100)  # % of the held-out task's episodes per variation
    fine_tune_steps: int = 20_000
    fine_tune_save_every: int = 5_000
    ablation_tasks: tuple[str, ...] = ("door",)
    ablation_variants: tuple[str, ...] = ()  # rows of the ablations recipe (empty: every variant it knows)
    learning_tasks: tuple[str, ...] = ("door",)
    learning_methods: tuple[str, ...] = ("mosaic",)
    variations: tuple[int, ...] = ()  # collected, trained on and evaluated (empty: every variation of each task)
    action_noise: str = ""  # --action-noise POS[,ROT] (DART) for the Panda's collection, the Sawyer's clean; "": none
    train_options: tuple[str, ...] = ()  # more lerobot-train options for every run, space-separated in --set
    # More lerobot-train options for new MOSAIC models only (this project's additions the baselines lack); the
    # ablations recipe leaves them out, its rows are the paper's MOSAIC with one change.
    mosaic_options: tuple[str, ...] = ()
    workers: int = 2  # collection and evaluation processes (local executor)
    executor: str = "local"  # collection and evaluation on local processes, or "ray" (every CPU of the cluster)
    ray_address: str = ""  # the Ray cluster with executor=ray; empty: Ray on this machine
    device: str = "cpu"  # --policy.device of lerobot-train
    num_workers: int = 2  # lerobot-train data loader workers

    def to_json(self) -> dict[str, Any]:
        return {key: list(value) if isinstance(value, tuple) else value for key, value in asdict(self).items()}


CPU_MOSAIC_OPTIONS: tuple[str, ...] = (
    "--policy.demo_summary=true", "--policy.variation_loss_weight=20", "--policy.hand_relative_targets=true",
    "--policy.n_mixtures=1", "--policy.wrong_demo_loss_weight=10", "--policy.temporal_ensemble_coeff=0.01",
    "--policy.weight_average_decay=0.998",
)
"""The ``cpu`` preset's MOSAIC options, this project's additions to the paper's model. The first three let MOSAIC
open the demonstrated door after half an hour of training on 2 cores but press one button whichever it is shown;
one logistic per action dimension with the wrong-demonstration loss makes it press the demonstrated button as well,
at the same success on door. The last two are how the checkpoint acts, not how it learns. ACT's temporal
ensembling (a chunk every control step, each target the mean of the chunks that cover it) took door from 65.0% to
75.0% over four runs' same weights and press_button from 81.7% to 93.1% over three. Acting with the weights
averaged over about the last 500 steps (the trained ones are kept beside them in the checkpoint) lifted four door
runs by 12.5-47.5 points each over their trained weights on the same episodes: the trained weights at the last step
get some variations right and miss others. With all seven, five door runs reach 83.2% and one press_button run
95.0% (docs/cpu_learning.md)."""

PRESETS: dict[str, ExperimentPreset] = {
    "paper": ExperimentPreset(device="cuda", workers=8, num_workers=4),
    # Under an hour of training per MOSAIC model on 2 cores with the small conv trunk and CPU_MOSAIC_OPTIONS (45-54 min
    # alone, a median 1.4 s per step at batch 16, 48x88, the wrong demonstration's pass included; the paper's resnet18
    # trunk: 2.5 s without it); 10-step action chunks; novel-task models train on 3 tasks.
    "cpu": ExperimentPreset(
        image_size="48x88", episodes=40, steps=2250, batch_size=16, vision_backbone="conv", save_every=750,
        train_options=("--policy.action_chunk=10",),
        mosaic_options=CPU_MOSAIC_OPTIONS,
        eval_checkpoints=1, eval_episodes=20, seeds=1, single_task_tasks=("door", "press_button"), multi_task_tasks=("door", "drawer", "press_button"),
        novel_task_pool=("door", "drawer", "press_button"), novel_task_tasks=("door",), fine_tune_tasks=("door",),
        fine_tune_steps=900, fine_tune_save_every=300, num_workers=1,
    ),
    # A training idea tried in about 12 minutes on 2 cores: door's right door pushed and pulled (variations 2 and 3),
    # 20 episodes each, 500 steps, one checkpoint evaluated on 10 held-out instances per variation.
    "quick": ExperimentPreset(
        image_size="48x88", episodes=20, steps=500, batch_size=16, vision_backbone="conv", save_every=500,
        eval_checkpoints=1, eval_episodes=10, seeds=1, variations=(2, 3), single_task_tasks=("door",),
        multi_task_tasks=("door",), novel_task_pool=("door", "press_button"), novel_task_tasks=("door",),
        fine_tune_tasks=("door",), fine_tune_steps=300, fine_tune_save_every=100, num_workers=1,
    ),
    # Minutes, end to end; CI runs learning and fine-tune with it, MOSAIC with the cpu preset's options.
    "smoke": ExperimentPreset(
        image_size="32x56", episodes=1, steps=2, batch_size=4, train_obs_frames=2, vision_backbone="conv", save_every=2,
        mosaic_options=CPU_MOSAIC_OPTIONS,
        eval_checkpoints=1, eval_episodes=1, eval_max_steps=8, seeds=1, single_task_tasks=("door",), multi_task_tasks=("door", "press_button"),
        novel_task_pool=("door", "press_button"), novel_task_tasks=("door",), fine_tune_tasks=("door",),
        fine_tune_fractions=(50, 100), fine_tune_steps=2, fine_tune_save_every=1, ablation_tasks=("door",),
        num_workers=0,
    ),
}


OPTION_FIELDS: dict[str, str] = {
    "train_options": "--policy.action_chunk=10 --policy.attention_pattern=full",
    "mosaic_options": "--policy.demo_summary=true",
}
"""Preset fields that hold lerobot-train options, each with the example its error gives."""


def _parse_value(name: str, current: Any, text: str) -> Any:
    if name in OPTION_FIELDS:  # command-line options hold commas (--dataset.episodes=[0,1]): split on spaces
        return tuple(text.split())
    if name == "variations":
        return tuple(int(item) for item in text.split(",") if item)
    if isinstance(current, tuple):
        items = [item for item in text.split(",") if item]
        return tuple(int(item) for item in items) if current and isinstance(current[0], int) else tuple(items)
    if isinstance(current, int):
        return int(text)
    return text


def resolve_preset(name: str, overrides: list[str]) -> ExperimentPreset:
    """The preset ``name`` with ``key=value`` overrides (lists comma-separated); ExperimentError on a bad one."""
    if name not in PRESETS:
        raise ExperimentError(f"unknown preset {name!r}: choose one of {', '.join(PRESETS)}")
    preset = PRESETS[name]
    known = {field.name for field in fields(ExperimentPreset)}
    changes: dict[str, Any] = {}
    for override in overrides:
        key, sep, text = override.partition("=")
        if not sep or key not in known:
            raise ExperimentError(
                f"bad --set {override!r}: use KEY=VALUE with KEY one of {', '.join(sorted(known))}"
            )
        try:
            changes[key] = _parse_value(key, getattr(preset, key), text)
        except ValueError:
            raise ExperimentError(f"bad --set {override!r}: {key} takes {type(getattr(preset, key)).__name__} values") from None
    resolved = replace(preset, **changes)
    check_preset(resolved)
    return resolved


def check_preset(preset: ExperimentPreset) -> None:
    """One clear line for budgets that cannot run (unknown tasks or methods, no checkpoint to evaluate)."""
    for key in ("single_task_tasks", "multi_task_tasks", "novel_task_pool", "novel_task_tasks", "fine_tune_tasks",
                "ablation_tasks", "learning_tasks"):
        check_tasks(getattr(preset, key), f"preset {key}")
    for key in ("methods", "fine_tune_methods", "learning_methods"):
        unknown = [m for m in getattr(preset, key) if m not in POLICY_TYPES]
        if unknown or not getattr(preset, key):
            raise ExperimentError(f"preset {key} {','.join(unknown) or '(empty)'}: choose from {', '.join(POLICY_TYPES)}")
    for key in ("episodes", "steps", "batch_size", "save_every", "eval_checkpoints", "eval_episodes", "seeds",
                "fine_tune_steps", "fine_tune_save_every", "workers"):
        if getattr(preset, key) < 1:
            raise ExperimentError(f"preset {key}={getattr(preset, key)}: it must be at least 1")
    if any(not 0 < f <= 100 for f in preset.fine_tune_fractions) or not preset.fine_tune_fractions:
        raise ExperimentError(f"preset fine_tune_fractions={preset.fine_tune_fractions}: give percentages in 1..100")
    if preset.vision_backbone not in VISION_BACKBONES:
        raise ExperimentError(
            f"preset vision_backbone={preset.vision_backbone!r}: choose {' or '.join(VISION_BACKBONES)}"
        )
    if preset.executor not in ("local", "ray"):
        raise ExperimentError(f"preset executor={preset.executor!r}: choose local or ray")
    if preset.ray_address and preset.executor != "ray":
        raise ExperimentError("preset ray_address needs executor=ray: add --set executor=ray")
    if any(v < 0 for v in preset.variations) or len(set(preset.variations)) != len(preset.variations):
        raise ExperimentError(f"preset variations={preset.variations}: give distinct variation numbers (0, 1, ...)")
    if preset.action_noise:
        from mosaic_data.action_noise import parse_action_noise

        try:
            parse_action_noise(preset.action_noise)
        except ValueError as error:
            raise ExperimentError(f"preset action_noise: {error}") from None
    for key, example in OPTION_FIELDS.items():
        if any(not option.startswith("--") for option in getattr(preset, key)):
            raise ExperimentError(
                f"preset {key}={' '.join(getattr(preset, key))!r}: give lerobot-train options, e.g. "
                f"--set '{key}={example}'"
            )
    height, _, width = preset.image_size.partition("x")
    if not (height.isdigit() and width.isdigit()):
        raise ExperimentError(f"preset image_size={preset.image_size!r}: write it HxW, e.g. 100x180")


def check_tasks(tasks: tuple[str, ...] | list[str], what: str = "--tasks") -> tuple[str, ...]:
    unknown = [task for task in tasks if task not in TASK_NAMES]
    if unknown or not tasks:
        raise ExperimentError(
            f"{what}: unknown task {', '.join(map(repr, unknown)) or '(none given)'}: choose from {', '.join(TASK_NAMES)}"
        )
    return tuple(tasks)


def saved_steps(steps: int, save_every: int) -> list[int]:
    """Steps at which lerobot-train saves a checkpoint: every ``save_every`` and the last one."""
    saved = list(range(save_every, steps + 1, save_every))
    if not saved or saved[-1] != steps:
        saved.append(steps)
    return saved
