"""Benchmark of ``mosaic-data collect --executor ray``: frames/s with N Ray workers against N local worker processes,
in the same run on this machine, and an estimate of the paper-size suite's wall time on a cluster.

Prints figures (it asserts nothing). Both executors collect the same dataset (the same shards and seeds); the order
alternates over ``--repeats`` so that a noisy, shared machine weighs on both alike. Figures:

* end to end: frames / wall time of the whole command (Ray's start-up and the merge included);
* steady state: frames / (rollout + writing time inside the workers), per worker;
* Ray's overhead as the ratio Ray / local of both;
* the peak resident memory of a worker (what ``mosaic_data.collection.ray_executor.COLLECT_WORKER`` asks for).

The cluster estimate scales the per-worker steady-state rate measured here (one core per worker) to nodes of
``--node-cores`` cores and ``--node-memory-gb`` memory: workers per node = min(cores, memory / peak memory per
worker). It assumes a node's core renders as fast as one here and ignores the merges (seconds per dataset).

Usage: ``MUJOCO_GL=egl python pipelines/bench/ray_bench.py --task door --variations 0,1,2,3 --episodes 4``
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("MUJOCO_GL", "egl")

from pipelines.bench.collect_bench import collect_rate  # noqa: E402

PAPER_SUITE_EPISODES = 61 * 100 * 2
"""61 variations x 100 episodes x 2 robots."""
SUITE_FRAMES_PER_EPISODE = 13322 / 122
"""Measured: ``mosaic-data collect --task all --episodes 1`` wrote 13322 frames in its 122 episodes (every task)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--task", default="door")
    parser.add_argument("--robot", default="panda")
    parser.add_argument("--variations", default="0,1,2,3", help="comma-separated")
    parser.add_argument("--episodes", type=int, default=4, help="per variation")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1, help="runs of each executor, alternating")
    parser.add_argument("--node-cores", type=int, default=16)
    parser.add_argument("--node-memory-gb", type=float, default=64.0)
    parser.add_argument("--nodes", default="1,2,4,8", help="cluster sizes to estimate, comma-separated")
    args = parser.parse_args()
    variations = [int(v) for v in args.variations.split(",")]
    from mosaic_data.collection.quiet import quiet_dataset_writing

    quiet_dataset_writing()
    print(f"collect {args.task}/{args.robot}, variations {variations}, {args.episodes} episodes each, 100x180 frames, "
          f"{args.workers} workers, {os.cpu_count()} CPUs here", flush=True)
    figures: dict[str, list] = {"local": [], "ray": []}
    for repeat in range(args.repeats):
        for executor in (("local", "ray") if repeat % 2 == 0 else ("ray", "local")):
            report = collect_rate(args.task, args.robot, variations, args.episodes, args.workers, executor)
            end_to_end = report.frames_collected / report.wall_s
            steady = report.frames_collected / (report.rollout_s + report.write_s)  # per worker
            figures[executor].append((end_to_end, steady, report.worker_peak_rss_mb, report.frames_collected, report.wall_s))
            print(f"{executor:5s}: {end_to_end:6.1f} frames/s end to end ({report.frames_collected} frames in "
                  f"{report.wall_s:.1f} s), {steady:5.1f} frames/s per worker in steady state, "
                  f"peak memory {report.worker_peak_rss_mb:.0f} MB per worker", flush=True)

    def mean(executor: str, index: int) -> float:
        return sum(f[index] for f in figures[executor]) / len(figures[executor])

    print(f"Ray / local: end to end {mean('ray', 0) / mean('local', 0):.2f}x, steady state per worker "
          f"{mean('ray', 1) / mean('local', 1):.2f}x (same run)")

    per_worker = mean("ray", 1)
    peak_gb = max(f[2] for f in figures["ray"] + figures["local"]) / 1024
    suite_frames = PAPER_SUITE_EPISODES * SUITE_FRAMES_PER_EPISODE
    workers_per_node = max(1, min(args.node_cores, int(args.node_memory_gb // max(peak_gb, 0.1))))
    print(f"\nestimate, paper-size suite: {PAPER_SUITE_EPISODES} episodes x {SUITE_FRAMES_PER_EPISODE:.0f} frames (the "
          f"suite's mean, measured) = {suite_frames / 1e6:.2f} M frames at {per_worker:.1f} frames/s per Ray worker "
          f"({args.task}'s rate here; scenes differ), {peak_gb:.1f} GB per worker -> {workers_per_node} workers per "
          f"{args.node_cores}-core, {args.node_memory_gb:.0f} GB node")
    for nodes in (int(n) for n in args.nodes.split(",")):
        hours = suite_frames / (nodes * workers_per_node * per_worker) / 3600
        print(f"  {nodes:3d} node(s): {hours:5.1f} h")


if __name__ == "__main__":
    main()
