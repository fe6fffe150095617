"""``mosaic-data``: the data-side command line (task table, expert rollouts, dataset collection and tools).

Exit status (:mod:`mosaic_data.exit_status`): 0 on success, 1 when experts miss their success target, a collection
cannot finish or a dataset fails validation, 2 on bad input (one-line error), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import defaultdict
from pathlib import Path

from mosaic_data.cli_args import MAX_EPISODES, OneLineErrorParser, episode_count, non_negative_int, parse_int_list
from mosaic_data.collection import CollectionError
from mosaic_data.exit_status import ExitContract

os.environ.setdefault("MUJOCO_GL", "egl")


def _robots(choice: str) -> list[str]:
    return ["panda", "sawyer"] if choice == "both" else [choice]


def cmd_tasks(args: argparse.Namespace) -> int:
    from mosaic_data.envs import gym_id
    from mosaic_data.tasks import TASK_NAMES, get_task_spec  # the table only, not the simulator

    tasks = [args.task] if args.task else list(TASK_NAMES)
    total = 0
    for task in tasks:
        spec = get_task_spec(task)
        print(f"{task} ({gym_id(task)}, {len(spec.variations)} variations, horizon {spec.horizon_steps} steps)")
        for variation in spec.variations:
            print(f"  {variation.index:>2}  {variation.description}")
        total += len(spec.variations)
    print(f"{len(tasks)} tasks, {total} variations")
    return 0


def cmd_experts(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from mosaic_data.recording_files import check_output_file
    from mosaic_data.rollout import SUCCESS_TARGET, expert_episodes, write_rerun, write_video
    from mosaic_data.tasks import get_task_class

    task_class = get_task_class(args.task)
    variations = args.variations if args.variations is not None else [v.index for v in task_class.variations]
    for variation in variations:
        task_class.validate_variation(variation)
    if not 1 <= args.episodes <= MAX_EPISODES:  # the parser's type bounds it already; a caller may skip the parser
        raise ValueError(f"--episodes must be from 1 to {MAX_EPISODES} per variation and robot, got {args.episodes}")
    if args.video is not None:
        check_output_file(args.video, ".mp4", "--video", f"{args.task}.mp4")  # before minutes of rollouts
    if args.rerun is not None:
        check_output_file(args.rerun, ".rrd", "--rerun", f"{args.task}.rrd")
    output = args.video or args.rerun
    seeds = [args.seed + i for i in range(args.episodes)]
    robots = _robots(args.robot)
    record = output is not None
    results: dict[tuple[str, int], list] = defaultdict(list)
    recorded = []
    total = len(robots) * len(variations) * len(seeds)
    with tqdm(total=total, desc=f"{args.task} experts", unit="episode") as progress:
        for robot in robots:
            for episode in expert_episodes(args.task, robot, variations, seeds, record_frames=record):
                results[(robot, episode.variation)].append(episode)
                if record:
                    recorded.append(episode)
                progress.update(1)
                progress.set_postfix(robot=robot, variation=episode.variation)
    print(f"{'robot':<8}{'var':>4}  {'success':>8}  {'mean len':>8}  description")
    all_ok = True
    for (robot, variation), episodes in results.items():
        rate = sum(e.success for e in episodes) / len(episodes)
        mean_length = sum(e.length for e in episodes) / len(episodes)
        flag = "" if rate >= SUCCESS_TARGET else "  <- below target"
        all_ok &= rate >= SUCCESS_TARGET
        print(f"{robot:<8}{variation:>4}  {rate:>8.0%}  {mean_length:>8.1f}  {task_class.variations[variation].description}{flag}")
    if args.video:
        write_video(args.video, recorded)
        print(f"video written to {args.video}")
    if args.rerun:
        write_rerun(args.rerun, recorded)
        print(f"rerun recording written to {args.rerun} (open with: rerun {args.rerun})")
    if not all_ok:
        print(f"some variations are below the {SUCCESS_TARGET:.0%} success target", file=sys.stderr)
    return 0 if all_ok else 1


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="mosaic-data", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    defaults = argparse.ArgumentDefaultsHelpFormatter

    tasks = sub.add_parser("tasks", help="print the task and variation table", formatter_class=defaults)
    tasks.add_argument("--task", default=None, help="only this task (default: all)")
    tasks.set_defaults(func=cmd_tasks)

    experts = sub.add_parser(
        "experts", help="roll the scripted experts out and report success per variation", formatter_class=defaults
    )
    experts.add_argument("--task", required=True, help="task key, e.g. door (see `mosaic-data tasks`)")
    experts.add_argument("--robot", default="both", choices=["panda", "sawyer", "both"])
    experts.add_argument(
        "--episodes", type=episode_count, default=20, help=f"episodes (fresh seeds) per variation and robot, at most {MAX_EPISODES}"
    )
    experts.add_argument("--variations", type=parse_int_list, default=None, help="e.g. 0,3 (default: all)")
    experts.add_argument("--seed", type=non_negative_int, default=0, help="first instance seed; episode k uses seed+k")
    output = experts.add_mutually_exclusive_group()
    output.add_argument("--video", type=Path, default=None, help="write all episodes to this .mp4 file (checked before any rollout)")
    output.add_argument("--rerun", type=Path, default=None, help="write a rerun recording to this .rrd file (checked before any rollout)")
    experts.set_defaults(func=cmd_experts)

    from mosaic_data.collection.cli import add_collection_commands

    add_collection_commands(sub)
    return parser


EXIT = ExitContract("mosaic-data", bad_input=(ValueError, FileNotFoundError), failure=(CollectionError,))
"""A collection that cannot finish (an expert gives up) is a failure, not a bad input."""


def main(argv: list[str] | None = None) -> int:
    return EXIT.main(build_parser(), argv, lambda args: args.func(args))


if __name__ == "__main__":
    sys.exit(main())
