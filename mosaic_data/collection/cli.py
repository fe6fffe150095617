"""The dataset subcommands of ``mosaic-data``: collect, merge, validate, view, push."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from mosaic_data.cli_args import parse_image_size, parse_int_list


def cmd_collect(args: argparse.Namespace) -> int:
    from mosaic_data.collection.collect import CollectRequest, collect
    from mosaic_data.collection.quiet import quiet_dataset_writing

    quiet_dataset_writing()  # the merges run in this process
    request = CollectRequest(
        task=args.task,
        robots=["panda", "sawyer"] if args.robot == "both" else [args.robot],
        variations=args.variations,
        episodes=args.episodes,
        workers=args.workers,
        output_dir=args.output_dir,
        seed=args.seed,
        overwrite=args.overwrite,
        image_height=args.image_size[0],
        image_width=args.image_size[1],
    )
    try:
        report = collect(request, show_progress=not args.quiet)
    except KeyboardInterrupt:
        print("mosaic-data: interrupted; finished shards are kept: run the same command again to resume", file=sys.stderr)
        return 130
    for outcome in report.datasets:
        print(
            f"{outcome.repo_id}: {outcome.status}, {outcome.episodes} episodes, {outcome.frames} frames, "
            f"{outcome.retries} expert retries -> {outcome.root}"
        )
    if report.frames_collected:
        print(
            f"collected {report.episodes_collected} episodes ({report.frames_collected} frames) in {report.wall_s:.1f} s: "
            f"{report.frames_collected / report.wall_s:.1f} frames/s with {args.workers} worker(s), "
            f"peak memory {report.worker_peak_rss_mb:.0f} MB per worker"
        )
    return 0


def cmd_merge(args: argparse.Namespace) -> int:
    from mosaic_data.collection.merge import merge_datasets
    from mosaic_data.collection.quiet import quiet_dataset_writing
    from mosaic_data.collection.schema import dataset_root, resolve_dataset

    quiet_dataset_writing()
    sources = [resolve_dataset(name, args.output_dir) for name in args.datasets]
    root = dataset_root(args.output_dir, args.repo_id)
    if root.exists() and not args.overwrite:
        raise ValueError(f"{root} already exists: choose another --repo-id, or add --overwrite to replace it")
    if root.exists() and not root.is_dir():
        raise ValueError(f"{root} is a file, not a dataset folder: choose another --repo-id")
    sidecar = merge_datasets(sources, args.repo_id, root)
    print(f"{args.repo_id}: merged {len(sources)} datasets, {len(sidecar['episodes'])} episodes -> {root}")
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    from mosaic_data.collection.schema import resolve_dataset
    from mosaic_data.collection.validate import validate_dataset

    root = resolve_dataset(args.dataset, args.output_dir)
    summary, problems = validate_dataset(root)
    if problems:
        print(f"{root}: {len(problems)} problem(s):", file=sys.stderr)
        for problem in problems:
            print(f"  - {problem}", file=sys.stderr)
        return 1
    print(f"{root}: OK ({summary})")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from mosaic_data.collection.schema import resolve_dataset
    from mosaic_data.collection.view import view_episode

    root = resolve_dataset(args.dataset, args.output_dir)
    pair_root = resolve_dataset(args.pair_with, args.output_dir) if args.pair_with else None
    if args.save is not None:
        parent = args.save.expanduser().absolute().parent
        if not parent.is_dir() or not os.access(parent, os.W_OK):
            raise ValueError(f"cannot write {args.save}: its folder {parent} is missing or not writable")
    message = view_episode(root, args.episode, pair=args.pair or pair_root is not None, pair_root=pair_root, save=args.save)
    print(message)
    return 0


def cmd_push(args: argparse.Namespace) -> int:
    from mosaic_data.collection.hub import push_dataset
    from mosaic_data.collection.schema import resolve_dataset

    root = resolve_dataset(args.dataset, args.output_dir)
    url = push_dataset(root, args.repo_id, private=args.private, push_videos=not args.no_videos)
    print(f"pushed {root} to {url}")
    return 0


def add_collection_commands(sub) -> None:
    """Add the dataset subcommands to ``mosaic-data``'s subparsers."""
    defaults = argparse.ArgumentDefaultsHelpFormatter
    where = "folder holding <repo_id> datasets; None means LeRobot's HF_LEROBOT_HOME"

    collect = sub.add_parser(
        "collect",
        help="collect successful expert episodes into LeRobot datasets mosaic/<task>_<robot>",
        description="Collect successful expert episodes of every variation into LeRobot v3 datasets. "
        "Interrupted runs resume where they stopped when run again with the same options.",
        formatter_class=defaults,
    )
    collect.add_argument("--task", required=True, help="task key (see `mosaic-data tasks`), or 'all' for the suite plus merged mosaic/all_<robot>")
    collect.add_argument("--robot", default="both", choices=["panda", "sawyer", "both"])
    collect.add_argument("--variations", type=parse_int_list, default=None, help="e.g. 0,3,5; None means every variation")
    collect.add_argument("--episodes", type=int, default=100, help="successful episodes per variation and robot")
    collect.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="worker processes")
    collect.add_argument("--output-dir", type=Path, default=None, help=where)
    collect.add_argument("--seed", type=int, default=0, help="base seed; episode seeds follow from it (see meta/mosaic.json)")
    collect.add_argument("--overwrite", action="store_true", help="redo datasets that already exist, and discard unfinished runs")
    collect.add_argument("--quiet", action="store_true", help="no progress bar")
    collect.add_argument(
        "--image-size", type=parse_image_size, default=(100, 180),
        help="camera HxW; the paper's is 100x180, smaller sizes (e.g. 48x88) suit CPU training runs",
    )
    collect.set_defaults(func=cmd_collect)

    merge = sub.add_parser("merge", help="merge datasets of one robot into one with LeRobot's aggregation", formatter_class=defaults)
    merge.add_argument("datasets", nargs="+", help="dataset folders or repo ids, e.g. mosaic/door_panda mosaic/drawer_panda")
    merge.add_argument("--repo-id", required=True, help="repo id of the merged dataset, e.g. mosaic/door_drawer_panda")
    merge.add_argument("--output-dir", type=Path, default=None, help=where)
    merge.add_argument("--overwrite", action="store_true", help="replace an existing merged dataset")
    merge.set_defaults(func=cmd_merge)

    validate = sub.add_parser("validate", help="check a dataset: schema, counts, videos, metadata", formatter_class=defaults)
    validate.add_argument("dataset", help="dataset folder or repo id")
    validate.add_argument("--output-dir", type=Path, default=None, help=where)
    validate.set_defaults(func=cmd_validate)

    view = sub.add_parser("view", help="show an episode in rerun (camera, state, action, success)", formatter_class=defaults)
    view.add_argument("dataset", help="dataset folder or repo id")
    view.add_argument("--episode", type=int, default=0, help="episode index")
    view.add_argument("--pair", action="store_true", help="show a demonstrator (sawyer) episode of the same variation beside it")
    view.add_argument("--pair-with", default=None, help="the other robot's dataset for --pair; None means the sibling mosaic/<task>_<other robot>")
    view.add_argument("--save", type=Path, default=None, help="write an .rrd file instead of opening the viewer")
    view.add_argument("--output-dir", type=Path, default=None, help=where)
    view.set_defaults(func=cmd_view)

    push = sub.add_parser("push", help="upload a dataset to the Hugging Face hub with a dataset card", formatter_class=defaults)
    push.add_argument("dataset", help="dataset folder or repo id")
    push.add_argument("--repo-id", required=True, help="hub repo id, e.g. your-name/mosaic_door_panda")
    push.add_argument("--private", action="store_true", help="create a private repository")
    push.add_argument("--no-videos", action="store_true", help="upload everything but the videos")
    push.add_argument("--output-dir", type=Path, default=None, help=where)
    push.set_defaults(func=cmd_push)
