"""The dataset subcommands of ``mosaic-data``: collect, merge, validate, view, push."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from mosaic_data.cli_args import action_noise, add_executor_arguments, episode_count, non_negative_int, parse_image_size, parse_int_list, positive_int
from mosaic_data.exit_status import Stopped, interrupted_status


def cmd_collect(args: argparse.Namespace) -> int:
    from mosaic_data.collection.collect import CollectRequest, collect, plan_jobs  # no simulator, LeRobot or Ray

    request = CollectRequest(
        task=args.task,
        robots=["panda", "sawyer"] if args.robot == "both" else [args.robot],
        variations=args.variations,
        episodes=args.episodes,
        workers=args.workers,
        output_dir=args.output_dir,
        executor=args.executor,
        ray_address=args.ray_address,
        seed=args.seed,
        overwrite=args.overwrite,
        image_height=args.image_size[0],
        image_width=args.image_size[1],
        action_noise=args.action_noise,
    )
    plan_jobs(request)  # every input, in a blink: before the seconds of LeRobot's imports below
    from mosaic_data.collection.quiet import quiet_dataset_writing

    quiet_dataset_writing()  # the merges run in this process
    try:
        report = collect(request, show_progress=not args.quiet)
    except KeyboardInterrupt as stop:
        raise Stopped(interrupted_status(stop), "interrupted; finished shards are kept: run the same command again to resume") from None
    for outcome in report.datasets:
        print(
            f"{outcome.repo_id}: {outcome.status}, {outcome.episodes} episodes, {outcome.frames} frames, "
            f"{outcome.retries} expert retries -> {outcome.root}"
        )
    if report.frames_collected:
        print(
            f"collected {report.episodes_collected} episodes ({report.frames_collected} frames) in {report.wall_s:.1f} s: "
            f"{report.frames_collected / report.wall_s:.1f} frames/s with {report.workers_used} worker(s), "
            f"peak memory {report.worker_peak_rss_mb:.0f} MB per worker"
        )
    return 0


def cmd_merge(args: argparse.Namespace) -> int:
    from mosaic_data.collection.merge import check_replaceable, merge_datasets, remove_stale_work
    from mosaic_data.collection.quiet import quiet_dataset_writing
    from mosaic_data.collection.schema import check_output_dir, dataset_root, resolve_dataset

    root = dataset_root(args.output_dir, args.repo_id)  # first: an empty or bare --repo-id must not name a folder
    check_output_dir(args.output_dir, args.repo_id.split("/")[0])  # a file in the way: now, not after the merge's work
    sources = [resolve_dataset(name, args.output_dir) for name in args.datasets]
    remove_stale_work(root)  # a killed merge's leftovers: its old dataset comes back before we look
    if (root.exists() or root.is_symlink()) and not args.overwrite:
        raise ValueError(f"{root} already exists: choose another --repo-id, or add --overwrite to replace it")
    check_replaceable(root)  # --overwrite replaces one dataset folder, never a folder of other things
    quiet_dataset_writing()  # LeRobot's bars off: its import takes seconds, so only once the inputs are checked
    sidecar = merge_datasets(sources, args.repo_id, root)
    print(f"{args.repo_id}: merged {len(sources)} datasets, {len(sidecar['episodes'])} episodes -> {root}")
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    from mosaic_data.collection.schema import resolve_dataset
    from mosaic_data.collection.validate import validate_dataset

    root = resolve_dataset(args.dataset, args.output_dir)
    warnings: list[str] = []
    summary, problems = validate_dataset(root, warnings)
    for warning in warnings:  # unusual but valid, e.g. episodes removed with lerobot-edit-dataset
        print(f"mosaic-data: warning: {warning}", file=sys.stderr)
    if problems:
        print(f"{root}: {len(problems)} problem(s):", file=sys.stderr)
        for problem in problems:
            print(f"  - {problem}", file=sys.stderr)
        return 1
    print(f"{root}: OK ({summary})")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from mosaic_data.collection.schema import resolve_dataset
    from mosaic_data.collection.view import WebPorts, default_save_name, has_display, view_episode
    from mosaic_data.recording_files import check_output_file

    root = resolve_dataset(args.dataset, args.output_dir)
    pair_root = resolve_dataset(args.pair_with, args.output_dir) if args.pair_with else None
    pair = args.pair or pair_root is not None
    if args.save is not None:  # a folder is refused, not filled with a made-up name: the one-line error names one
        check_output_file(args.save, ".rrd", "--save", default_save_name(root, args.episode, pair))
    elif not args.web and not has_display():
        raise ValueError(
            "no display to open rerun's viewer on (DISPLAY and WAYLAND_DISPLAY are unset): add --save episode.rrd "
            "to write a file, or --web to serve rerun's web viewer on localhost"
        )
    if args.web and args.web_port == args.grpc_port:
        raise ValueError(f"--web-port and --grpc-port are both {args.web_port}: the two servers need two ports")
    web = WebPorts(args.web_port, args.grpc_port) if args.web else None
    message = view_episode(root, args.episode, pair=pair, pair_root=pair_root, save=args.save, web=web)
    print(message)
    if web is not None:
        # Served after Ctrl-C: the recording was flushed before serving and nothing is left to write. rerun's exit hooks
        # (shutting its web and gRPC servers down) were seen to hang for minutes on a loaded machine, so the
        # process ends here instead of in the interpreter's shutdown.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    return 0


def cmd_push(args: argparse.Namespace) -> int:
    from mosaic_data.collection.hub import push_dataset
    from mosaic_data.collection.schema import check_repo_id, resolve_dataset

    check_repo_id(args.repo_id, "--repo-id")  # before anything is read or written
    root = resolve_dataset(args.dataset, args.output_dir)
    result = push_dataset(root, args.repo_id, private=args.private, push_videos=not args.no_videos, dry_run=args.dry_run)
    for warning in result.warnings:
        print(f"mosaic-data: warning: {warning}", file=sys.stderr)
    print(result.message)
    return 0


def add_collection_commands(sub) -> None:
    """Add the dataset subcommands to ``mosaic-data``'s subparsers."""
    defaults = argparse.ArgumentDefaultsHelpFormatter
    where = "folder holding <repo_id> datasets; None means LeRobot's HF_LEROBOT_HOME"

    collect = sub.add_parser(
        "collect",
        help="collect successful expert episodes into LeRobot datasets mosaic/<task>_<robot>",
        description="Collect successful expert episodes of every variation into LeRobot v3 datasets. "
        "Interrupted runs resume where they stopped when run again with the same options, --overwrite included: "
        "its finished shards are kept.",
        formatter_class=defaults,
    )
    collect.add_argument("--task", required=True, help="task key (see `mosaic-data tasks`), or 'all' for the suite plus merged mosaic/all_<robot>")
    collect.add_argument("--robot", default="both", choices=["panda", "sawyer", "both"])
    collect.add_argument("--variations", type=parse_int_list, default=None, help="e.g. 0,3,5; None means every variation")
    collect.add_argument("--episodes", type=episode_count, default=100, help="successful episodes per variation and robot")
    collect.add_argument(
        "--workers", type=positive_int, default=None,
        help="shards collected at once; None means one per core here, or per CPU of the Ray cluster with --executor ray",
    )
    add_executor_arguments(collect, "collection workers")
    collect.add_argument("--output-dir", type=Path, default=None, help=where)
    collect.add_argument("--seed", type=non_negative_int, default=0, help="base seed; episode seeds follow from it (see meta/mosaic.json)")
    collect.add_argument(
        "--overwrite", action="store_true",
        help="replace datasets that already exist (once the new one is complete) and discard unfinished runs of "
        "other settings; an unfinished run of these same settings resumes. It replaces only LeRobot dataset "
        "folders (or empty ones), never a folder with other content",
    )
    collect.add_argument("--quiet", action="store_true", help="no progress bar")
    collect.add_argument(
        "--image-size", type=parse_image_size, default=(100, 180),
        help="camera HxW; the paper's is 100x180, smaller sizes (e.g. 48x88) suit CPU training runs",
    )
    collect.add_argument(
        "--action-noise", type=action_noise, default=None, metavar="POS_STD_M[,ROT_STD_RAD]",
        help="DART-style noise injection: the simulator executes each expert action with Gaussian noise on its target "
        "position (std in m) and orientation (std in rad per axis), never the gripper, while the dataset records the "
        "expert's clean action, so the episodes show the expert correcting small errors. Without ROT_STD_RAD it is "
        "4 rad per metre of POS_STD_M (0.005 -> 0.02); 0.005 suits the suite. None (or 0) means no noise. The "
        "setting is recorded in meta/mosaic.json",
    )
    collect.set_defaults(func=cmd_collect)

    merge = sub.add_parser(
        "merge", help="merge datasets of one robot into one with LeRobot's aggregation", formatter_class=defaults,
        description="Merge datasets of one robot and image size, with no episode in two of them, into "
        "<output-dir>/<repo-id>. It is built beside its place and renamed in when complete; a disk that fills up "
        "stops it with the sources and any old dataset there untouched.",
    )
    merge.add_argument("datasets", nargs="+", help="dataset folders or repo ids, e.g. mosaic/door_panda mosaic/drawer_panda")
    merge.add_argument("--repo-id", required=True, help="repo id namespace/name of the merged dataset, e.g. mosaic/door_drawer_panda")
    merge.add_argument("--output-dir", type=Path, default=None, help=where)
    merge.add_argument("--overwrite", action="store_true", help="replace an existing merged dataset (only a LeRobot dataset folder, or an empty one)")
    merge.set_defaults(func=cmd_merge)

    validate = sub.add_parser("validate", help="check a dataset: schema, counts, videos, metadata", formatter_class=defaults)
    validate.add_argument("dataset", help="dataset folder or repo id")
    validate.add_argument("--output-dir", type=Path, default=None, help=where)
    validate.set_defaults(func=cmd_validate)

    view = sub.add_parser("view", help="show an episode in rerun (camera, state, action, success)", formatter_class=defaults)
    view.add_argument("dataset", help="dataset folder or repo id")
    view.add_argument("--episode", type=non_negative_int, default=0, help="episode index")
    view.add_argument("--pair", action="store_true", help="show a demonstrator (sawyer) episode of the same variation beside it")
    view.add_argument("--pair-with", default=None, help="the other robot's dataset for --pair; None means the sibling mosaic/<task>_<other robot>")
    out = view.add_mutually_exclusive_group()
    out.add_argument("--save", type=Path, default=None, help="write this .rrd file instead of opening the viewer (a file name, not a folder)")
    out.add_argument(
        "--web", action="store_true",
        help="serve rerun's web viewer on localhost instead (no display needed); prints its URL, serves until Ctrl-C",
    )
    view.add_argument("--web-port", type=positive_int, default=9090, help="HTTP port of the web viewer, with --web")
    view.add_argument("--grpc-port", type=positive_int, default=9876, help="port the web viewer reads the recording from, with --web")
    view.add_argument("--output-dir", type=Path, default=None, help=where)
    view.set_defaults(func=cmd_view)

    push = sub.add_parser(
        "push", help="upload a dataset to the Hugging Face hub with a dataset card", formatter_class=defaults,
        description="Upload a dataset (meta/mosaic.json included) to the Hugging Face hub with a dataset card. "
        "Needs a network connection and a login (`hf auth login`); HF_HUB_OFFLINE=1 (set by scripts/setup.sh) must "
        "be unset. --dry-run writes the card to <dataset>/README.md and uploads nothing.",
    )
    push.add_argument("dataset", help="dataset folder or repo id")
    push.add_argument("--repo-id", required=True, help="hub repo id, e.g. your-name/mosaic_door_panda")
    push.add_argument("--private", action="store_true", help="create a private repository")
    push.add_argument("--no-videos", action="store_true", help="upload everything but the videos")
    push.add_argument(
        "--dry-run", action="store_true",
        help="write the dataset card to <dataset>/README.md and say what would be uploaded; nothing is uploaded",
    )
    push.add_argument("--output-dir", type=Path, default=None, help=where)
    push.set_defaults(func=cmd_push)
