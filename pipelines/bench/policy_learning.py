"""Does a policy learn to do what ONE demonstration shows? Collect, train, evaluate one-shot, in one command.

    python -m pipelines.bench.policy_learning --task door --preset cpu --output DIR
    python -m pipelines.bench.policy_learning --task door --preset quick --output DIR   # the learning check

`quick` tries an idea in about 15 minutes on 2 cores: two variations (2,3: on door the right door, pushed and
pulled), 20 episodes each per robot, 500 training steps, one checkpoint evaluated on 10 held-out instances per
variation. Compare two settings on one dataset with `--data-dir` shared between their runs.

Every stage is the tool a user runs by hand, as a subprocess, so the figures are those of the shipped commands:

1. `mosaic-data collect --task door --robot both ...` writes the agent (Panda) and demonstrator (Sawyer)
   datasets under DIR/data (reused when already complete: the collector resumes or leaves them alone);
2. `lerobot-train --policy.type=mosaic ...` (or a baseline's type, `--policy-type`) trains on them and saves checkpoints every `save_every` steps;
3. `mosaic-eval --policy.path=<checkpoint> ...` rolls out every saved checkpoint on held-out instances (seeds
   from 10^9, never collected) with a fresh Sawyer demonstration per episode (another held-out instance).

DIR/results.json holds the settings, the time of each stage, the learning curve (one-shot success of every
checkpoint, and how often the wrong variation was achieved) and the final checkpoint's per-variation success
and confusion matrix; DIR/learning_curve.png plots the curve, and each checkpoint's evaluation folder holds
mosaic-eval's results.md and confusion-matrix PNG. `--preset` picks sizes for the machine; any option below
overrides it, and extra `lerobot-train` options go after `--`, e.g. `-- --policy.use_state=true`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from mosaic_data.constants import POLICY_TYPES


@dataclass(frozen=True)
class Preset:
    """Sizes of one learning run. `cpu` is about 50 minutes of MOSAIC training on 2 CPU cores with the small conv
    trunk (lerobot-train's updt_s 1.0-1.1 s per step; `--vision-backbone resnet18`: 2-2.5 s per step, about 2
    hours); `quick` a learning check of about 12 minutes in all; `paper` is the paper's sizes."""

    image_size: str = "48x88"
    episodes: int = 40  # per variation and robot
    steps: int = 2700
    batch_size: int = 16
    train_obs_frames: int = 7
    save_every: int = 900
    eval_episodes: int = 10  # per variation and checkpoint
    eval_max_steps: int | None = None  # cap on an evaluation episode (None: the task's horizon)
    vision_backbone: str = "conv"  # --policy.vision_backbone: the small CPU trunk; "resnet18" is the paper's
    variations: str | None = None  # collected, trained on and evaluated (None: every variation of the task)
    policy_options: tuple[str, ...] = field(default_factory=tuple)


PRESETS: dict[str, Preset] = {
    "cpu": Preset(),
    "paper": Preset(
        image_size="100x180", episodes=100, steps=40_000, batch_size=30, train_obs_frames=7, save_every=10_000,
        vision_backbone="resnet18",
    ),
    # the quick learning check: about 15 minutes on 2 cores with `--variations` naming two (default 2,3 for
    # door, the right door pushed and pulled); one checkpoint, evaluated on 10 held-out instances per variation
    "quick": Preset(episodes=20, steps=500, save_every=500, eval_episodes=10, variations="2,3"),
    # the whole pipeline in about two minutes (a test): nothing is learned
    "smoke": Preset(
        image_size="32x56", episodes=2, steps=4, batch_size=4, train_obs_frames=2, save_every=2, eval_episodes=1,
        eval_max_steps=10,
    ),
}


def parse_args(argv: list[str] | None = None) -> tuple[argparse.Namespace, list[str]]:
    parser = argparse.ArgumentParser(
        prog="python -m pipelines.bench.policy_learning",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--task", default="door", help="task (see `mosaic-data tasks`)")
    parser.add_argument("--policy-type", default="mosaic", choices=list(POLICY_TYPES),
                        help="policy to train: MOSAIC or one of the paper's baselines (default mosaic)")
    parser.add_argument("--variations", default=None,
                        help="e.g. 0,2 (default: the preset's: 2,3 for quick, else every variation)")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="cpu")
    parser.add_argument("--output", type=Path, required=True, help="folder for data, checkpoints and results")
    parser.add_argument("--data-dir", type=Path, default=None,
                        help="datasets folder (default: OUTPUT/data); share one between runs that compare options")
    for name, kind in (("image-size", str), ("episodes", int), ("steps", int), ("batch-size", int),
                       ("train-obs-frames", int), ("save-every", int), ("eval-episodes", int)):
        parser.add_argument(f"--{name}", type=kind, default=None, help="overrides the preset")
    parser.add_argument("--vision-backbone", choices=("resnet18", "conv"), default=None,
                        help="vision trunk (--policy.vision_backbone), overrides the preset: resnet18 (the paper's) or "
                             "conv (small, for CPU; the cpu and smoke presets' choice)")
    parser.add_argument("--action-noise", default=None, metavar="POS_STD_M[,ROT_STD_RAD]",
                        help="collect with DART-style noise injection (mosaic-data collect --action-noise); give it "
                             "its own --data-dir, since the datasets differ")
    parser.add_argument("--workers", type=int, default=2, help="collection and evaluation processes")
    parser.add_argument("--seed", type=int, default=1000, help="training seed")
    parser.add_argument("--eval-only", action="store_true", help="evaluate the checkpoints already in DIR/train")
    argv = sys.argv[1:] if argv is None else argv
    extra: list[str] = []
    if "--" in argv:
        argv, extra = argv[: argv.index("--")], argv[argv.index("--") + 1 :]
    return parser.parse_args(argv), extra


def resolve_preset(args: argparse.Namespace, extra: list[str]) -> Preset:
    preset = PRESETS[args.preset]
    overrides = {
        key: getattr(args, key)
        for key in ("image_size", "episodes", "steps", "batch_size", "train_obs_frames", "save_every", "eval_episodes",
                    "vision_backbone", "variations")
        if getattr(args, key) is not None
    }
    return replace(preset, **overrides, policy_options=tuple(extra))


def _bin(name: str) -> str:
    """A console script of this environment (the venv's, whatever PATH says)."""
    return str(Path(sys.executable).parent / name)


COMMANDS: list[str] = []
"""Every stage's command line, in order, for results.json."""


def _run(command: list[str], log: Path) -> float:
    """Run a stage, its output into `log` (and a one-line summary on screen); seconds taken. Exits on failure."""
    print(f"$ {' '.join(command)}", flush=True)
    COMMANDS.append(" ".join(command))
    start = time.perf_counter()
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    with log.open("w") as out:
        result = subprocess.run(command, stdout=out, stderr=subprocess.STDOUT, env=env)
    seconds = time.perf_counter() - start
    if result.returncode != 0:
        tail = "".join(log.read_text().splitlines(keepends=True)[-15:])
        sys.exit(f"{tail}\npolicy_learning: `{Path(command[0]).name}` failed (exit {result.returncode}); full log: {log}")
    print(f"  done in {seconds / 60:.1f} min (log: {log})", flush=True)
    return seconds


def collect(args: argparse.Namespace, preset: Preset, data_dir: Path) -> float:
    command = [_bin("mosaic-data"), "collect", "--task", args.task, "--robot", "both", "--episodes", str(preset.episodes),
               "--image-size", preset.image_size, "--workers", str(args.workers), "--output-dir", str(data_dir), "--quiet"]
    if preset.variations:
        command += ["--variations", preset.variations]
    if args.action_noise:
        command += ["--action-noise", args.action_noise]
    return _run(command, args.output / "collect.log")


def train(args: argparse.Namespace, preset: Preset, data_dir: Path, train_dir: Path) -> float:
    agent, demo = f"mosaic/{args.task}_panda", f"mosaic/{args.task}_sawyer"
    command = [
        _bin("lerobot-train"),
        f"--policy.type={args.policy_type}",
        f"--dataset.repo_id={agent}",
        f"--dataset.root={data_dir / agent}",
        f"--policy.demo_repo_id={demo}",
        f"--policy.demo_root={data_dir / demo}",
        f"--policy.train_obs_frames={preset.train_obs_frames}",
        f"--policy.vision_backbone={preset.vision_backbone}",
        "--policy.push_to_hub=false",
        "--policy.device=cpu",
        f"--batch_size={preset.batch_size}",
        f"--steps={preset.steps}",
        f"--save_freq={preset.save_every}",
        "--log_freq=50",
        "--num_workers=1",
        f"--seed={args.seed}",
        f"--output_dir={train_dir}",
        *preset.policy_options,
    ]
    return _run(command, args.output / "train.log")


def checkpoints(train_dir: Path) -> list[tuple[int, Path]]:
    """(step, pretrained_model folder) of every checkpoint lerobot-train saved, in step order."""
    found = []
    for folder in (train_dir / "checkpoints").iterdir():
        if folder.name.isdigit() and (folder / "pretrained_model" / "model.safetensors").is_file():
            found.append((int(folder.name), folder / "pretrained_model"))
    return sorted(found)


def evaluate(args: argparse.Namespace, preset: Preset, checkpoint: Path, out: Path) -> tuple[float, dict]:
    out.mkdir(parents=True, exist_ok=True)
    command = [_bin("mosaic-eval"), f"--policy.path={checkpoint}", "--task", args.task,
               "--episodes-per-variation", str(preset.eval_episodes), "--workers", str(args.workers),
               "--output", str(out / "results.json"), "--quiet"]
    if preset.variations:
        command += ["--variations", preset.variations]
    if preset.eval_max_steps:
        command += ["--max-steps", str(preset.eval_max_steps)]
    seconds = _run(command, out / "eval.log")
    return seconds, json.loads((out / "results.json").read_text())


def summarise(results: dict, task: str) -> dict:
    """Success and wrong-variation share of one checkpoint's mosaic-eval results, per variation and overall."""
    table = next(iter(results["tables"].values()))  # one agent: the checkpoint
    task_row = next(row for row in table["per_task"] if row["task"] == task)
    return {
        "success": task_row["mean"],
        "episodes": task_row["instances"],
        "ci95": [task_row["ci95_low"], task_row["ci95_high"]],
        "per_variation": {str(row["variation"]): row["mean"] for row in table["per_variation"] if row["task"] == task},
        "wrong_variation_share": task_row["confusion"]["wrong_variation_share"],
        "confusion": task_row["confusion"],
    }


def plot_learning_curve(curve: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [point["step"] for point in curve]
    figure, axis = plt.subplots(figsize=(6, 3.6), dpi=120)
    axis.plot(steps, [100 * p["success"] for p in curve], "o-", label="one-shot success")
    axis.plot(steps, [100 * (p["wrong_variation_share"] or 0) for p in curve], "s--", label="wrong variation done")
    variations = sorted({v for p in curve for v in p["per_variation"]}, key=int)
    for variation in variations:
        axis.plot(steps, [100 * p["per_variation"].get(variation, 0) for p in curve], ":", alpha=0.6, label=f"variation {variation}")
    axis.set(xlabel="training steps", ylabel="% of episodes", ylim=(-3, 103), title=title)
    axis.grid(alpha=0.3)
    axis.legend(fontsize=7, loc="best")
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    args, extra = parse_args(argv)
    preset = resolve_preset(args, extra)
    args.output.mkdir(parents=True, exist_ok=True)
    data_dir, train_dir = args.data_dir or args.output / "data", args.output / "train"
    seconds: dict[str, float] = {}
    if not args.eval_only:
        seconds["collect"] = collect(args, preset, data_dir)
        if train_dir.exists():
            sys.exit(f"policy_learning: {train_dir} already exists: use another --output, or --eval-only to evaluate it")
        seconds["train"] = train(args, preset, data_dir, train_dir)
    if not (train_dir / "checkpoints").is_dir():
        sys.exit(f"policy_learning: no checkpoints in {train_dir}: run without --eval-only first")
    curve = []
    seconds["evaluate"] = 0.0
    for step, checkpoint in checkpoints(train_dir):
        eval_seconds, results = evaluate(args, preset, checkpoint, args.output / "eval" / f"step_{step:06d}")
        seconds["evaluate"] += eval_seconds
        point = {"step": step, **summarise(results, args.task)}
        curve.append(point)
        low, high = point["ci95"]
        print(f"  step {step}: one-shot success {100 * point['success']:.0f}% [95% interval {100 * low:.0f}-"
              f"{100 * high:.0f}%, {point['episodes']} episodes], wrong variation "
              f"{100 * (point['wrong_variation_share'] or 0):.0f}%, per variation "
              + ", ".join(f"{k}: {100 * v:.0f}%" for k, v in point["per_variation"].items()), flush=True)
    plot_learning_curve(
        curve, args.output / "learning_curve.png", f"{args.task}, {args.policy_type}: one-shot success vs training steps"
    )
    summary = {
        "task": args.task,
        "policy_type": args.policy_type,
        "variations": preset.variations or "all",
        "preset": args.preset,
        "settings": asdict(preset),
        "seconds": seconds,
        "commands": COMMANDS,
        "learning_curve": curve,
        "final": curve[-1] if curve else None,
    }
    (args.output / "results.json").write_text(json.dumps(summary, indent=2))
    print(f"results: {args.output / 'results.json'}, curve: {args.output / 'learning_curve.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
