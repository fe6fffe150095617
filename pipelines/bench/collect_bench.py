"""Benchmark of ``mosaic-data collect``: frames/s against the bare env step+render rate, 1 vs 2 workers.

Prints figures (it asserts nothing). All numbers come from this run on this machine:

* bare: the task env stepping with the expert and rendering every frame, no writing: one process rendering
  with every core (what one worker gets), and two processes at once with one render thread each (what two
  workers get: the most they could reach without writing anything);
* collect, 1 and 2 workers: the real pipeline (expert, retries, LeRobot writing, AV1 encoding, shard merge),
  frames/s over the whole command including worker start-up and the final merge, and in steady state
  (rollout + writing time inside the workers);
* peak resident memory of a worker.

Usage: ``MUJOCO_GL=egl python pipelines/bench/collect_bench.py --task door --variations 0,1,2,3 --episodes 8``
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")


def bare_rate(task: str, robot: str, variations: list[int], episodes: int) -> tuple[float, int]:
    """Frames/s of env step + render + expert, no dataset writing, in this process."""
    from mosaic_data.collection.plan import episode_seed
    from mosaic_data.rollout import run_expert_episode
    from mosaic_data.tasks import make_task_env

    frames, seconds = 0, 0.0
    for variation in variations:
        env = make_task_env(task, variation, robot)
        try:
            for slot in range(episodes):
                started = time.perf_counter()
                episode = run_expert_episode(env, episode_seed(0, variation, slot, 0), record_frames=True, record_final_frame=False)
                seconds += time.perf_counter() - started
                frames += episode.length
        finally:
            env.close()
    return frames / seconds, frames


def _bare_rate_in_child(task: str, robot: str, variations: list[int], episodes: int, results) -> None:
    results.put(bare_rate(task, robot, variations, episodes))


def parallel_bare_rate(task: str, robot: str, variations: list[int], episodes: int, processes: int = 2) -> float:
    """Total frames/s of ``processes`` bare loops at once, one render thread each (as collect's workers)."""
    import multiprocessing

    from mosaic_data.process_env import scoped_environment

    context = multiprocessing.get_context("spawn")
    results = context.Queue()
    with scoped_environment(force={"LP_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}):
        children = [context.Process(target=_bare_rate_in_child, args=(task, robot, variations, episodes, results)) for _ in range(processes)]
        for child in children:
            child.start()
    rates = [results.get()[0] for _ in children]
    for child in children:
        child.join()
    return sum(rates)


def collect_rate(task: str, robot: str, variations: list[int], episodes: int, workers: int, executor: str = "local"):
    """The report of a real ``collect`` into a temporary folder (removed afterwards), on ``executor``."""
    from mosaic_data.collection.collect import CollectRequest, collect

    output = Path(tempfile.mkdtemp(prefix=f"mosaic_collect_bench_{executor}_"))
    try:
        report = collect(
            CollectRequest(task=task, robots=[robot], variations=variations, episodes=episodes, workers=workers,
                           output_dir=output, executor=executor),
            show_progress=False,
        )
    finally:
        shutil.rmtree(output, ignore_errors=True)
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--task", default="door")
    parser.add_argument("--robot", default="panda")
    parser.add_argument("--variations", default="0,1", help="comma-separated")
    parser.add_argument("--episodes", type=int, default=2, help="per variation")
    args = parser.parse_args()
    variations = [int(v) for v in args.variations.split(",")]
    from mosaic_data.collection.quiet import quiet_dataset_writing

    quiet_dataset_writing()  # the merges run in this process
    print(f"task {args.task}, robot {args.robot}, variations {variations}, {args.episodes} episodes each, "
          f"100x180 frames, {os.cpu_count()} CPUs")
    bare, frames = bare_rate(args.task, args.robot, variations, args.episodes)
    print(f"bare env step+render+expert, 1 process: {bare:6.1f} frames/s ({frames} frames)", flush=True)
    bare_two = parallel_bare_rate(args.task, args.robot, variations, args.episodes)
    print(f"bare, 2 processes at once (1 render thread each): {bare_two:6.1f} frames/s in total", flush=True)
    one = None
    for workers in (1, 2):
        report = collect_rate(args.task, args.robot, variations, args.episodes, workers)
        rate = report.frames_collected / report.wall_s
        steady = report.frames_collected / (report.rollout_s + report.write_s)
        line = (
            f"collect, {workers} worker(s): {rate:6.1f} frames/s end to end ({report.frames_collected} frames in "
            f"{report.wall_s:.1f} s); per worker, rollout {report.rollout_s:.1f} s + writing {report.write_s:.1f} s "
            f"= {steady:.1f} frames/s; peak memory per worker {report.worker_peak_rss_mb:.0f} MB"
        )
        if workers == 1:
            one = rate
            line += f"; vs bare 1 process: {rate / bare:.2f}x end to end, {steady / bare:.2f}x steady state"
        else:
            line += (f"; speed-up vs 1 worker: {rate / one:.2f}x end to end; "
                     f"vs 2 bare processes: {rate / bare_two:.2f}x end to end, {workers * steady / bare_two:.2f}x steady state")
        print(line, flush=True)


if __name__ == "__main__":
    main()
