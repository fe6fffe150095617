"""Benchmark: paired-sample throughput (agent 7-frame windows + demonstrator 4-frame demos) per worker.

    python -m pipelines.bench.policy_loader [--episodes 3] [--length 60] [--step-seconds 2.0]

Writes a small pair of 100x180 datasets (4 variations) with LeRobot's writer in a temp dir, then measures in
one process: agent samples/s as lerobot-train's loader reads them (7 frames + state + actions), demonstrator
samples/s of `PairedDemoSampler` decoding synchronously, and, with its background threads, how long a
training step still waits for the demos of a batch of 30 when the step itself takes --step-seconds
(simulated by sleeping, so the decoding threads get the CPU the real step would share with them).
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from mosaic_data.constants import ACTION_KEY, CAMERA_KEY, FPS, N_DEMO_FRAMES, STATE_KEY


def write_pair(base: Path, episodes: int, length: int, height: int, width: int) -> tuple[Path, Path]:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: its tests package
    from tests.helpers.policy import write_dataset  # LeRobotDataset.create / add_frame / save_episode

    agent = write_dataset(base / "agent", "mosaic/bench_panda", [0, 1, 2, 3], episodes, length, height, width)
    demo = write_dataset(base / "demo", "mosaic/bench_sawyer", [0, 1, 2, 3], episodes, length, height, width)
    return agent, demo


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=3, help="episodes per variation and robot")
    parser.add_argument("--length", type=int, default=60, help="frames per episode")
    parser.add_argument("--samples", type=int, default=120)
    parser.add_argument("--batch-size", type=int, default=30)
    parser.add_argument("--step-seconds", type=float, default=2.0, help="simulated training step time")
    parser.add_argument("--threads", type=int, default=2, help="demo decoding threads")
    args = parser.parse_args()
    torch.set_num_threads(1)

    from lerobot.datasets import LeRobotDataset

    from mosaic_policy.common.paired_sampling import PairedDemoSampler

    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        agent_root, demo_root = write_pair(Path(tmp), args.episodes, args.length, 100, 180)
        print(f"wrote 2 x {4 * args.episodes * args.length} frames at 100x180 in {time.perf_counter() - start:.1f} s")

        from mosaic_policy import MosaicConfig

        config = MosaicConfig()  # the paper's window: 7 frames 0.25 s apart, the 35 actions under them
        frames = [i / FPS for i in config.observation_delta_indices]
        actions = [i / FPS for i in config.action_delta_indices]
        agent = LeRobotDataset(
            "mosaic/bench_panda",
            root=agent_root,
            delta_timestamps={CAMERA_KEY: frames, STATE_KEY: frames, ACTION_KEY: actions},
            return_uint8=True,
        )
        rng = np.random.default_rng(0)
        indices = rng.integers(0, len(agent), args.samples)
        agent[0]
        start = time.perf_counter()
        items = [agent[int(i)] for i in indices]
        agent_rate = args.samples / (time.perf_counter() - start)
        print(f"agent samples (7 frames + state + actions): {agent_rate:.1f} samples/s per worker")

        tasks = [item["task"] for item in items]
        episodes = [int(item["episode_index"]) for item in items]
        sync = PairedDemoSampler("mosaic/bench_sawyer", demo_root, CAMERA_KEY, N_DEMO_FRAMES, agent_meta=agent.meta, threads=0)
        sync.sample(tasks[:2], episodes[:2])
        start = time.perf_counter()
        for i in range(0, args.samples, args.batch_size):
            sync.sample(tasks[i : i + args.batch_size], episodes[i : i + args.batch_size])
        demo_rate = args.samples / (time.perf_counter() - start)
        print(f"demonstrator samples (4 frames), synchronous: {demo_rate:.1f} samples/s")
        paired = 1.0 / (1.0 / agent_rate + 1.0 / demo_rate)
        print(f"paired samples, one worker doing both: {paired:.1f} samples/s")

        threaded = PairedDemoSampler(
            "mosaic/bench_sawyer", demo_root, CAMERA_KEY, N_DEMO_FRAMES, agent_meta=agent.meta, threads=args.threads
        )
        waits = []
        for i in range(0, args.samples, args.batch_size):
            batch_tasks, batch_episodes = tasks[i : i + args.batch_size], episodes[i : i + args.batch_size]
            threaded.sample(batch_tasks, batch_episodes)
            waits.append(threaded.last_wait_s)
            time.sleep(args.step_seconds)
        threaded.close()
        print(
            f"with {args.threads} decoding threads and a {args.step_seconds:.1f} s step: wait per batch of "
            f"{args.batch_size}: first {waits[0] * 1e3:.0f} ms (cold), then median "
            f"{np.median(waits[1:]) * 1e3:.1f} ms"
        )


if __name__ == "__main__":
    main()
