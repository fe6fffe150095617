"""``mosaic-eval``: one-shot evaluation of MOSAIC checkpoints (and the expert / untrained sanity rows).

    mosaic-eval --policy.path=outputs/train/door/checkpoints/last/pretrained_model --task door
    mosaic-eval --baseline expert --baseline untrained --task all --episodes-per-variation 10
    mosaic-eval --policy.path=outputs/train/door_act/checkpoints/last/pretrained_model --task door   # any LeRobot type

For every episode: a fresh demonstration of the variation by the demonstrator's (Sawyer's) expert on another
instance (or one drawn from ``--demo-dataset``), a fresh Panda instance, the policy's rollout up to the task's
horizon, success from the environment, and which variation's goal the agent reached. Prints success per
variation and per task (mean +- std, with the 95% Wilson interval of the rate and the episodes behind it: on
10 episodes the interval reaches up to 30 points from the rate) and the share of episodes that did the wrong
variation, writes JSON and Markdown (with a confusion matrix per task) and a heat map PNG per task, optionally
a rerun recording with the policy's attention.

Exit status (:mod:`mosaic_data.exit_status`): 0 when the evaluation ran, 2 on bad input (one line naming the fix),
1 when a rollout worker died (e.g. killed by the out-of-memory killer), 130 when interrupted. Every output path is
checked before any work, and an evaluation that stops early writes the episodes that finished as a partial report
(``"partial"`` in the JSON) and says so.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from mosaic_data.cli_args import (  # noqa: E402
    OneLineErrorParser,
    add_executor_arguments,
    episode_count,
    non_negative_int,
    parse_image_size,
    parse_int_list,
    positive_int,
)
from mosaic_data.exit_status import BAD_INPUT, FAILURE, ExitContract, Stopped, interrupted_status  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    from .options import BASELINES, EVAL_BASE_SEED, add_policy_option_arguments  # no torch, LeRobot or simulator for --help

    parser = OneLineErrorParser(
        prog="mosaic-eval",
        description="One-shot evaluation by simulated rollouts: success per variation and per task.",
    )
    parser.add_argument(
        "--policy.path", dest="policy_paths", action="append", default=[], metavar="DIR",
        help="policy checkpoint of any LeRobot type that sees the task camera and state, e.g. MOSAIC or ACT (a "
        "lerobot-train pretrained_model folder or run folder); repeat it for several checkpoints of one recipe (e.g. "
        "training seeds): checkpoints of one policy type form one row, mean +- std over them, confusion matrices summed",
    )
    add_policy_option_arguments(parser, "; set on every checkpoint (default: the checkpoint's)")
    parser.add_argument(
        "--baseline", action="append", default=[], choices=BASELINES,
        help="sanity rows through the same loop: the scripted expert, or MOSAIC at initialisation (repeatable)",
    )
    parser.add_argument("--task", required=True, help="task name (see `mosaic-data tasks`) or 'all'")
    parser.add_argument("--variations", type=parse_int_list, default=None, help="e.g. 0,1 (one task only; default all)")
    parser.add_argument("--episodes-per-variation", type=episode_count, default=10, help="episodes per variation (default 10)")
    parser.add_argument(
        "--workers", type=positive_int, default=None,
        help="episodes run at once (default: one per core here, or per CPU of the Ray cluster with --executor ray)",
    )
    add_executor_arguments(parser, "rollouts")
    parser.add_argument(
        "--max-steps", type=positive_int, default=None, metavar="N",
        help="cap every episode at N steps (smoke tests; default: the task's horizon)",
    )
    parser.add_argument(
        "--seed", type=non_negative_int, default=EVAL_BASE_SEED,
        help=f"base seed of the instances, as lerobot-eval's --seed: the same value gives the same episodes and numbers "
        f"there (default {EVAL_BASE_SEED}; lerobot-eval's is 1000)",
    )
    parser.add_argument(
        "--demo-dataset", default=None, metavar="DATASET",
        help="draw demonstrations from this demonstrator dataset (folder or repo id under $HF_LEROBOT_HOME) "
        "instead of running the demonstrator's expert",
    )
    parser.add_argument("--rerun", type=Path, default=None, metavar="OUT.rrd", help="save a rerun recording")
    parser.add_argument(
        "--rerun-episodes", type=positive_int, default=1, metavar="K",
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
    from .options import EvaluationError

    return ExitContract("mosaic-eval", bad_input=(EvaluationError,)).main(build_parser(), argv, run)


def run(args: argparse.Namespace) -> int:
    from .options import EvaluationError, WorkerDied, check_arguments

    check_arguments(args)  # a typo in --task: one line in a blink, before the seconds of the imports below
    from tqdm import tqdm

    from .plan import EvaluationPlan
    from .recording import EvaluationRecording
    from .report import check_output_paths, print_table, report_paths, summarize, timing, write_reports
    from .runner import in_plan_order, run_episodes
    from mosaic_data.ray_cluster import RayExecutorError

    output = args.output or Path("outputs/eval") / f"{dt.datetime.now():%Y-%m-%d/%H-%M-%S}_{args.task}" / "results.json"
    json_path, markdown_path = report_paths(output)
    if markdown_path == json_path:
        raise EvaluationError(f"--output {output} names the Markdown report's file: name the JSON one, e.g. results.json")
    outputs = {"--output": json_path, "--output's Markdown report": markdown_path}
    check_output_paths(outputs | ({"--rerun": args.rerun} if args.rerun else {}))  # before any work

    plan = EvaluationPlan.from_args(args)
    for warning in plan.warnings:
        print(f"mosaic-eval: warning: {warning}", file=sys.stderr)
    recording = EvaluationRecording(args.rerun, plan.n_demo_frames, args.attention_layer) if args.rerun else None
    progress = tqdm(total=len(plan.episodes), desc="episodes", unit="ep", disable=args.quiet, dynamic_ncols=True)
    finished = []  # every result as it arrives: what an evaluation that stops early still writes

    def on_result(result) -> None:
        finished.append(result)
        progress.update(1)
        progress.set_postfix(success=f"{sum(r.success for r in finished)}/{progress.n}")
        if recording is not None:
            recording.log_episode(result)

    workers = [args.workers or 1]  # the count that runs, once the executor knows it

    def on_workers(count: int) -> None:
        workers[0] = count

    start = time.perf_counter()

    def report_of(results: list) -> dict:
        return {
            "settings": plan.settings(),
            "tables": summarize(results, plan.groups),
            "timing": timing(results, time.perf_counter() - start, workers[0]),
            "episodes": [result.summary() for result in results],
        }

    try:
        results = run_episodes(
            plan.episodes, plan.agents, plan.demo_source, args.workers, on_result, args.max_steps, args.executor, args.ray_address,
            on_workers,
        )
    except (KeyboardInterrupt, Exception) as error:
        kept = _keep_partial(in_plan_order(finished, plan.episodes), len(plan.episodes), error, json_path, report_of)
        if isinstance(error, KeyboardInterrupt):
            raise Stopped(interrupted_status(error), f"interrupted; {kept}") from None
        if isinstance(error, WorkerDied):
            raise Stopped(FAILURE, f"error: {error}; {kept}; run it again, with fewer --workers if memory is short") from None
        if isinstance(error, (EvaluationError, RayExecutorError)):
            raise Stopped(BAD_INPUT, f"error: {error}; {kept}") from None
        print(f"mosaic-eval: {kept}", file=sys.stderr)
        raise
    finally:
        progress.close()
        if recording is not None:
            recording.close()
    report = report_of(results)
    tables = report["tables"]
    write_reports(json_path, report)
    heat_maps = _write_heat_maps(json_path.parent, tables)
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


def _keep_partial(finished: list, planned: int, error: BaseException, json_path: Path, report_of: Callable) -> str:
    """Write the episodes that finished before ``error`` as a partial report; returns what was done, for the message."""
    from .report import write_reports

    if not finished:
        return "no episode had finished, so no results were written"
    reason = (str(error).splitlines() or [type(error).__name__])[0] if not isinstance(error, KeyboardInterrupt) else "interrupted"
    report = report_of(finished) | {"partial": {"finished": len(finished), "planned": planned, "reason": reason}}
    try:
        write_reports(json_path, report)
    except OSError as write_error:
        return f"the {len(finished)} finished episodes could not be written to {json_path} ({write_error})"
    return f"wrote the {len(finished)} of {planned} episodes that finished to {json_path} (partial results)"


def _write_heat_maps(folder: Path, tables: dict) -> list[Path]:
    """The heat maps, after the results are written: a missing plotting library or an unwritable image file must
    not lose them."""
    from .confusion import write_heat_maps

    try:
        return write_heat_maps(folder, tables)
    except ImportError:
        print("mosaic-eval: no confusion heat maps: matplotlib is not installed (pip install matplotlib)", file=sys.stderr)
    except OSError as error:
        print(f"mosaic-eval: no confusion heat maps: {error}", file=sys.stderr)
    return []


if __name__ == "__main__":
    sys.exit(main())
