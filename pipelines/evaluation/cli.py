"""``mosaic-eval``: one-shot evaluation of MOSAIC checkpoints (and the expert / untrained sanity rows).

    mosaic-eval --policy.path=outputs/train/door/checkpoints/last/pretrained_model --task door
    mosaic-eval --baseline expert --baseline untrained --task all --episodes-per-variation 10
    mosaic-eval --policy.path=outputs/train/door_act/checkpoints/last/pretrained_model --task door   # any LeRobot type

For every episode: a fresh demonstration of the variation by the demonstrator's (Sawyer's) expert on another
instance (or one drawn from ``--demo-dataset``), a fresh Panda instance, the policy's rollout up to the task's
horizon, success from the environment, and which variation's goal the agent reached. Prints success per
variation and per task (mean +- std) and the share of episodes that did the wrong variation, writes JSON and
Markdown (with a confusion matrix per task) and a heat map PNG per task, optionally a rerun recording with the
policy's attention.

Exit status: 0 when the evaluation ran, 2 on bad input (one line naming the fix), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from mosaic_data.cli_args import parse_image_size, parse_int_list  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    from .agents import BASELINES
    from .rollouts import EVAL_BASE_SEED

    parser = argparse.ArgumentParser(
        prog="mosaic-eval",
        description="One-shot evaluation by simulated rollouts: success per variation and per task.",
    )
    parser.add_argument(
        "--policy.path", dest="policy_paths", action="append", default=[], metavar="DIR",
        help="policy checkpoint of any LeRobot type that sees the task camera and state, e.g. MOSAIC or ACT (a "
        "lerobot-train pretrained_model folder or run folder); repeat it for several checkpoints of one recipe (e.g. "
        "training seeds): checkpoints of one policy type form one row, mean +- std over them, confusion matrices summed",
    )
    parser.add_argument(
        "--baseline", action="append", default=[], choices=BASELINES,
        help="sanity rows through the same loop: the scripted expert, or MOSAIC at initialisation (repeatable)",
    )
    parser.add_argument("--task", required=True, help="task name (see `mosaic-data tasks`) or 'all'")
    parser.add_argument("--variations", type=parse_int_list, default=None, help="e.g. 0,1 (one task only; default all)")
    parser.add_argument("--episodes-per-variation", type=int, default=10, help="episodes per variation (default 10)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="rollout processes (default: all cores)")
    parser.add_argument(
        "--max-steps", type=int, default=None, metavar="N",
        help="cap every episode at N steps (smoke tests; default: the task's horizon)",
    )
    parser.add_argument("--seed", type=int, default=EVAL_BASE_SEED, help=f"base seed of the instances (default {EVAL_BASE_SEED})")
    parser.add_argument(
        "--demo-dataset", default=None, metavar="DATASET",
        help="draw demonstrations from this demonstrator dataset (folder or repo id under $HF_LEROBOT_HOME) "
        "instead of running the demonstrator's expert",
    )
    parser.add_argument("--rerun", type=Path, default=None, metavar="OUT.rrd", help="save a rerun recording")
    parser.add_argument(
        "--rerun-episodes", type=int, default=1, metavar="K",
        help="episodes recorded per variation and agent with --rerun (default 1)",
    )
    parser.add_argument("--attention-layer", type=int, default=-1, help="attention layer drawn in the recording (default: last)")
    parser.add_argument(
        "--output", type=Path, default=None, metavar="RESULTS.json",
        help="results file (JSON; Markdown beside it); default outputs/eval/<date>/<time>_<task>/results.json",
    )
    parser.add_argument(
        "--image-size", type=parse_image_size, default=None, metavar="HxW",
        help="camera size of the baselines when no checkpoint is given (default 100x180; else the checkpoint's)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from .agents import EvaluationError

    try:
        return run(args)
    except EvaluationError as error:
        print(f"mosaic-eval: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mosaic-eval: interrupted", file=sys.stderr)
        return 130


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from .confusion import write_heat_maps
    from .plan import EvaluationPlan
    from .recording import EvaluationRecording
    from .report import print_table, summarize, timing, write_reports
    from .runner import run_episodes

    plan = EvaluationPlan.from_args(args)
    output = args.output or Path("outputs/eval") / f"{dt.datetime.now():%Y-%m-%d/%H-%M-%S}_{args.task}" / "results.json"
    recording = EvaluationRecording(args.rerun, plan.n_demo_frames, args.attention_layer) if args.rerun else None
    progress = tqdm(total=len(plan.episodes), desc="episodes", unit="ep", disable=args.quiet, dynamic_ncols=True)
    successes = 0

    def on_result(result) -> None:
        nonlocal successes
        successes += result.success
        progress.update(1)
        progress.set_postfix(success=f"{successes}/{progress.n}")
        if recording is not None:
            recording.log_episode(result)

    start = time.perf_counter()
    try:
        results = run_episodes(plan.episodes, plan.agents, plan.demo_source, args.workers, on_result, args.max_steps)
    finally:
        progress.close()
        if recording is not None:
            recording.close()
    wall_s = time.perf_counter() - start
    tables = summarize(results, plan.groups)
    report = {
        "settings": plan.settings(),
        "tables": tables,
        "timing": timing(results, wall_s, min(args.workers, len(plan.episodes))),
        "episodes": [result.summary() for result in results],
    }
    json_path, markdown_path = write_reports(output, report)
    try:
        heat_maps = write_heat_maps(json_path.parent, tables)
    except ImportError:  # the results are written: a missing plotting library must not lose them
        heat_maps = []
        print("mosaic-eval: no confusion heat maps: matplotlib is not installed (pip install matplotlib)", file=sys.stderr)
    print(print_table(tables))
    figures = report["timing"]
    print(
        f"{figures['episodes']} episodes, {figures['steps']} steps in {figures['wall_s']:.1f} s on {figures['workers']} "
        f"worker(s): {figures['steps_per_s']} steps/s ({figures['steps_per_s_per_worker']} per worker, "
        f"agent {figures['act_ms_per_step']} ms/step)"
    )
    maps = "".join(f", {path.name}" for path in heat_maps[:3]) + (f" and {len(heat_maps) - 3} more" if len(heat_maps) > 3 else "")
    print(f"wrote {json_path}, {markdown_path}{maps}" + (f", rerun recording {args.rerun}" if args.rerun else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
