"""``mosaic-experiment``: the paper's experiments as one-command recipes, with tables beside the paper's numbers.

    mosaic-experiment list
    mosaic-experiment run single-task --preset cpu --output outputs/experiments/single_cpu [--tasks door,press_button]
    mosaic-experiment run fine-tune --preset smoke --dry-run        # the exact commands, nothing run
    mosaic-experiment report outputs/experiments/single_cpu

A run is a plan of stages, each a shipped command (``mosaic-data collect``/``merge``, ``lerobot-train``,
``mosaic-eval``) whose command line and log are kept under DIR/stages. Running it again skips finished stages;
a killed run resumes in the stage it was in. Several recipes may share one folder (fine-tune reuses novel-task's
models) when they use the same preset; the report covers all of them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from mosaic_data.cli_args import parse_image_size
from mosaic_data.exit_status import ExitContract

from .presets import PRESETS, ExperimentError, ExperimentPreset, check_tasks, resolve_preset
from .recipes import RECIPES, Plan, build_plan, check_episode_layout
from .stages import Stage, StageFailed, experiment_lock, is_done, run_stage, stage_folder, stage_seconds

EXPERIMENT_FILE = "experiment.json"
ASSUMED_GPU_SECONDS_PER_STEP = 0.3
"""Seconds per training step on one data-centre GPU at the paper's sizes: an assumption for the estimate the
``paper`` preset prints, not a measurement (lerobot-train's ``updt_s`` log shows the figure of your GPU)."""
MEASURED_ROLLOUT_STEPS_PER_S = 13.5
"""Control steps per second per evaluation worker with MOSAIC at 100x180, measured on this project's 2-core
machine (README, speed section): the rollout part of the estimate."""
MEASURED_CPU_SECONDS_PER_STEP = {"resnet18": 2.5, "conv": 0.7}
"""Seconds per MOSAIC training step on this project's 2-core machine at 48x88, batch 16, 7 frames (the ``cpu``
preset's sizes), per ``--policy.vision_backbone``: lerobot-train's ``updt_s`` (conv: 0.64-0.69 s over the unshared
stretches of a 5000-step run with batched augmentation; resnet18: a 500-step run with the per-sequence augmentation).
The training part of the estimate on ``--policy.device=cpu``, scaled by
batch size and pixels per image."""
DEMO_SUMMARY_STEP_RATIO = 1.09
"""A MOSAIC step with ``--policy.demo_summary=true`` against one without, on the 2-core machine with the conv trunk
(0.76 s per step over 4500- and 5000-step door runs alone, against 0.70)."""
WRONG_DEMO_STEP_RATIO = 1.8
"""A MOSAIC step with ``--policy.wrong_demo_loss_weight`` above 0 (one more attention pass and action head, for the
wrong demonstration) against one with the summary alone, on the 2-core machine with the conv trunk: 1.40 s for
the ``cpu`` preset's MOSAIC trained alone on press_button (lerobot-train's median ``updt_s`` over 2250 steps; 1.3
over the first 400) against the summary's 0.76 s."""
CPU_REFERENCE_SIZES = (16, 48, 88)
"""Batch size, height and width of the ``MEASURED_CPU_SECONDS_PER_STEP`` measurement."""
MEASURED_CPU_STEP_RATIO = {
    "conv": {"mosaic": 1.0, "tosil": 0.73, "lstm_osil": 0.43, "mlp_osil": 0.46, "daml": 0.94},
    "resnet18": {"mosaic": 1.0, "tosil": 0.64, "lstm_osil": 0.55, "mlp_osil": 0.56, "daml": 0.48},
}
"""Trunk -> policy type -> its lerobot-train step as a ratio to MOSAIC's, from ``python -m
pipelines.bench.policy_compare`` on this project's 2-core machine. conv, at the ``cpu`` preset's sizes
(``--batch-size 16 --height 48 --width 88 --vision-backbone conv --action-chunk 10 --threads 2 --steps 5``): the
model steps (MOSAIC 0.58 s, T-OSIL 0.39, LSTM 0.18, MLP 0.20, DAML 0.54) plus the 0.12 s of data loading that a
MOSAIC run adds (0.70 s per step in lerobot-train), e.g. LSTM (0.18 + 0.12) / 0.70; an LSTM run logged 0.28 s per
step. resnet18, at the paper's sizes (batch 30, 100x180; README): the model steps' ratios alone. MOSAIC's step also
runs its EMA target and contrastive losses, the baselines have none. It scales the training estimate of a baseline's run."""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="mosaic-experiment", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("list", help="the recipes and presets")
    run = commands.add_parser("run", help="run (or resume) a recipe and write its report")
    run.add_argument("recipe", help=f"one of {', '.join(RECIPES)}")
    run.add_argument("--preset", default="cpu", help=f"one of {', '.join(PRESETS)} (default cpu)")
    run.add_argument("--output", type=Path, default=None,
                     help="experiment folder (default outputs/experiments/<recipe>_<preset>)")
    run.add_argument("--data-dir", type=Path, default=None,
                     help="datasets folder (default OUTPUT/data); share one between experiments of the same preset")
    run.add_argument("--tasks", default=None, help="comma-separated tasks (default: the preset's for the recipe)")
    run.add_argument("--seeds", type=int, default=None, help="training seeds per cell (overrides the preset)")
    run.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                     help="override a preset field, e.g. --set steps=600 --set methods=mosaic,tosil")
    run.add_argument("--dry-run", action="store_true", help="print the commands it would run, run nothing")
    report = commands.add_parser("report", help="write DIR/results.md, results.json and figures from what has run")
    report.add_argument("output", type=Path)
    return parser.parse_args(argv)


def _duration(seconds: float, unit: str = "hours") -> str:
    """``"9.4 hours"``, or minutes below an hour (``"3 minutes"``) so a small plan does not read ``0.0 hours``."""
    if seconds < 3600:
        minutes = max(1, round(seconds / 60))
        return f"{minutes} {unit.replace('hours', 'minutes' if minutes > 1 else 'minute')}"
    return f"{seconds / 3600:.1f} {unit}"


def _count(number: int, noun: str) -> str:
    """``"1 training run"``, ``"3 training runs"``."""
    return f"{number} {noun}{'' if number == 1 else 's'}"


def _option_values(stage: Stage, name: str) -> list[str]:
    """The values of ``--NAME=VALUE`` in a stage's command, in the order given (empty when it is not there)."""
    return [a.split("=", 1)[1] for a in stage.command if a.startswith(f"--{name}=")]


def _train_steps(stage: Stage) -> int:
    return int(_option_values(stage, "steps")[0])


def _policy_type(stage: Stage) -> str | None:
    """The --policy.type of a training stage; None for a fine-tuned model (its type is in its checkpoint)."""
    return next(iter(_option_values(stage, "policy.type")), None)


def _demo_summary(stage: Stage) -> bool:
    """Whether a training stage trains with the demonstration summary (its last ``--policy.demo_summary`` true)."""
    values = _option_values(stage, "policy.demo_summary")
    return bool(values) and values[-1].lower() == "true"


def _wrong_demo_loss(stage: Stage) -> bool:
    """Whether a training stage trains with the wrong-demonstration loss (its last weight option above 0)."""
    weights = _option_values(stage, "policy.wrong_demo_loss_weight")
    return bool(weights) and float(weights[-1]) > 0


OPTION_STEP_COSTS = (
    (DEMO_SUMMARY_STEP_RATIO, "the demonstration summary", _demo_summary),
    (WRONG_DEMO_STEP_RATIO, "the wrong-demonstration loss", _wrong_demo_loss),
)
"""(step time ratio, what it pays for, whether a training stage uses it): the MOSAIC options whose measured cost
the CPU estimate multiplies into a run's steps and names in its text."""


def estimate_text(plan: Plan, preset: ExperimentPreset, output_dir: Path | None = None) -> str:
    """How much work a plan is: training steps, rollouts, and on a GPU preset the GPU-hours; with ``output_dir``,
    only the stages not finished there (an extended or resumed experiment)."""
    from mosaic_data.tasks.spec import TASK_SPECS

    stages = [s for s in plan.stages if output_dir is None or not is_done(output_dir, s)]
    finished = len(plan.stages) - len(stages)
    train = [s for s in stages if s.kind == "train"]
    steps = sum(_train_steps(s) for s in train)
    evaluations = [s for s in stages if s.kind == "evaluate"]
    rollout_steps = 0
    for stage in evaluations:
        task = stage.command[stage.command.index("--task") + 1]
        episodes = int(stage.command[stage.command.index("--episodes-per-variation") + 1])
        horizon = TASK_SPECS[task].horizon_steps
        if "--max-steps" in stage.command:
            horizon = min(horizon, int(stage.command[stage.command.index("--max-steps") + 1]))
        variations = (len(stage.command[stage.command.index("--variations") + 1].split(","))
                      if "--variations" in stage.command else len(TASK_SPECS[task].variations))
        rollout_steps += episodes * variations * horizon
    workers = max(1, preset.workers)
    left = f" left of {len(plan.stages)} ({finished} finished before)" if finished else ""
    text = (f"{_count(len(stages), 'stage')}{left}: {_count(len(train), 'training run')} ({steps} steps in all), "
            f"{_count(len(evaluations), 'evaluation')} (at most {rollout_steps} control steps, about "
            f"{_duration(rollout_steps / MEASURED_ROLLOUT_STEPS_PER_S, 'CPU-hours')} of rollouts at "
            f"{MEASURED_ROLLOUT_STEPS_PER_S} steps/s per worker, {workers} workers)")
    if preset.device == "cpu":
        height, width = parse_image_size(preset.image_size)
        batch, ref_height, ref_width = CPU_REFERENCE_SIZES
        measured = MEASURED_CPU_SECONDS_PER_STEP[preset.vision_backbone]
        per_step = measured * preset.batch_size * height * width / (batch * ref_height * ref_width)
        ratios = MEASURED_CPU_STEP_RATIO[preset.vision_backbone]
        types = [_policy_type(s) for s in train]
        costs = [[cost for cost in OPTION_STEP_COSTS if cost[2](s)] for s in train]
        seconds = sum(math.prod((ratio for ratio, _, _ in paid), start=_train_steps(s) * per_step * ratios.get(t, 1.0))
                      for s, t, paid in zip(train, types, costs))
        baselines = [b for b in ratios if b != "mosaic" and b in types]
        options = [f"{cost[0]}x with {cost[1]}" for cost in OPTION_STEP_COSTS if any(cost in paid for paid in costs)]
        text += (f"; training about {_duration(seconds)} on 2 CPU cores ({per_step:.2g} s per step of the paper's "
                 f"MOSAIC, scaled from {measured} s measured with the {preset.vision_backbone} trunk at "
                 f"{ref_height}x{ref_width}, batch {batch}"
                 + (f"; {', '.join(options)}" if options else "")
                 + (f"; a baseline's step: {', '.join(f'{b} {ratios[b]}x' for b in baselines)} of it" if baselines else "")
                 + ")")
    if preset.device == "cuda":
        text += (f"; training about {steps * ASSUMED_GPU_SECONDS_PER_STEP / 3600:.0f} GPU-hours at an assumed "
                 f"{ASSUMED_GPU_SECONDS_PER_STEP} s per step (not measured here)")
    return text


def _without_seeds(settings: dict[str, Any]) -> dict[str, Any]:
    """Settings that decide what every stage computes: the number of seeds only adds or leaves out whole runs
    (seed k's stages are the same whatever the count), so more seeds extend an experiment in place."""
    return {**settings, "overrides": [o for o in settings["overrides"] if not o.startswith("seeds=")]}


def _check_settings(output_dir: Path, args: argparse.Namespace, overrides: list[str], data_dir: Path | None) -> dict[str, Any]:
    """DIR/experiment.json's record with this run's settings in it (not written); ExperimentError if DIR holds this
    recipe with other settings, or another recipe with another preset or data (recipes sharing DIR share them)."""
    path = output_dir / EXPERIMENT_FILE
    record = json.loads(path.read_text()) if path.is_file() else {"recipes": {}}
    mine = {"preset": args.preset, "overrides": overrides, "tasks": args.tasks.split(",") if args.tasks else None,
            "data_dir": str(data_dir.absolute()) if data_dir else None}
    wanted = _without_seeds(mine)
    for recipe, theirs in record["recipes"].items():
        held = _without_seeds(theirs)
        same = all(held[k] == wanted[k] for k in ("preset", "overrides", "data_dir"))
        if recipe == args.recipe and held != wanted or not same:
            raise ExperimentError(
                f"{output_dir} holds a {recipe} run with other settings ({theirs['preset']} {' '.join(theirs['overrides'])}): "
                "rerun it with the same options to resume (--seeds may change), or use another --output"
            )
    record["recipes"][args.recipe] = mine
    return record


def _record_settings(output_dir: Path, args: argparse.Namespace, overrides: list[str], data_dir: Path | None) -> dict[str, Any]:
    """Write DIR/experiment.json, the recipes run in DIR and their settings, after `_check_settings`."""
    record = _check_settings(output_dir, args, overrides, data_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    (output_dir / EXPERIMENT_FILE).write_text(json.dumps(record, indent=2))
    return record


def _check_fraction_data(stage: Stage, episodes_per_variation: int) -> None:
    """A training run on a fraction of a dataset: the dataset must be numbered as the plan assumed."""
    if not _option_values(stage, "dataset.episodes"):
        return
    root = Path(_option_values(stage, "dataset.root")[0])
    repo = _option_values(stage, "dataset.repo_id")[0]
    check_episode_layout(root, repo.split("/")[1].removesuffix("_panda"), episodes_per_variation)


def run(args: argparse.Namespace) -> int:
    overrides = list(args.overrides) + ([f"seeds={args.seeds}"] if args.seeds is not None else [])
    preset = resolve_preset(args.preset, overrides)
    tasks = check_tasks(args.tasks.split(",")) if args.tasks else None
    output_dir = (args.output or Path("outputs/experiments") / f"{args.recipe}_{args.preset}").absolute()
    plan = build_plan(args.recipe, preset, output_dir, args.data_dir, tasks)
    print(f"mosaic-experiment {args.recipe}, preset {args.preset}: {estimate_text(plan, preset, output_dir)}", flush=True)
    if args.dry_run:
        _check_settings(output_dir, args, overrides, args.data_dir)
        for stage in plan.stages:
            state = " (done)" if is_done(output_dir, stage) else ""
            print(f"\n# {stage.title}{state}\n{stage.shell_line()}")
        return 0
    with experiment_lock(output_dir):
        _record_settings(output_dir, args, overrides, args.data_dir)
        total = len(plan.stages)
        for number, stage in enumerate(plan.stages, 1):
            prefix = f"[{number}/{total}] {stage.title}"
            if is_done(output_dir, stage):
                print(f"{prefix}: done before, skipped", flush=True)
                continue
            resume = (stage_folder(output_dir, stage) / "command.txt").is_file()
            if stage.kind == "train":
                _check_fraction_data(stage, preset.episodes)
            print(f"{prefix}{' (resuming)' if resume else ''} ...", flush=True)
            seconds = run_stage(output_dir, stage, resume)
            print(f"  done in {seconds / 60:.1f} min", flush=True)
    paths = report(output_dir)
    print(f"results: {paths['markdown']} (and results.json, figures/)")
    return 0


def report(output_dir: Path) -> dict[str, Path]:
    from .report import write_report

    path = output_dir / EXPERIMENT_FILE
    if not path.is_file():
        raise ExperimentError(f"{output_dir} holds no mosaic-experiment run: run `mosaic-experiment run RECIPE --output {output_dir}` first")
    record = json.loads(path.read_text())
    entries = []
    for recipe, settings in record["recipes"].items():
        preset = resolve_preset(settings["preset"], settings["overrides"])
        plan = build_plan(recipe, preset, output_dir, settings["data_dir"],
                          tuple(settings["tasks"]) if settings["tasks"] else None)
        seconds: dict[str, float] = {}
        for stage in plan.stages:
            seconds[stage.kind] = seconds.get(stage.kind, 0.0) + (stage_seconds(output_dir, stage) or 0.0)
        entries.append({"recipe": recipe, "preset_name": settings["preset"], "preset": preset,
                        "overrides": settings["overrides"], "plan": plan, "seconds": seconds})
    return write_report(output_dir, entries)


def list_recipes() -> int:
    print("recipes:")
    for name, (_, _, description) in RECIPES.items():
        print(f"  {name:12s} {description}")
    print("presets:")
    for name, p in PRESETS.items():
        print(f"  {name:6s} {p.image_size}, {p.episodes} episodes per variation and robot, {p.steps} steps at batch "
              f"{p.batch_size}, {p.seeds} seed(s), last {p.eval_checkpoints} checkpoint(s) x {p.eval_episodes} "
              f"episodes per variation, device {p.device}")
    return 0


EXIT = ExitContract(
    "mosaic-experiment", bad_input=(ExperimentError,), failure=(StageFailed,),
    bad_input_line="{command}: {error}",
    failure_line="{error}\n{command}: fix the cause and run the same command again: finished stages are kept",
    interrupted_line="\n{command}: interrupted; run the same command again to resume",
)
"""A failed stage's message names its log; a run resumes where it stopped, so the lines say to run it again."""


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    return EXIT.run(lambda: _command(args))


def _command(args: argparse.Namespace) -> int:
    try:
        if args.command == "list":
            return list_recipes()
        if args.command == "report":
            paths = report(args.output.absolute())
            print(f"results: {paths['markdown']} (and results.json, figures/)")
            return 0
        return run(args)
    except BrokenPipeError:  # `mosaic-experiment run ... --dry-run | head`: the reader has all it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    raise SystemExit(main())
