"""Benchmark: latency of one policy query with a cached demonstration (goal: <= 15 ms median on a 2-core CPU).

    python -m pipelines.bench.policy_latency [--calls 100] [--threads 1 2]

Paper settings (2 attention layers, 100x180). `set_demo` runs once (its time is printed too); every call
then runs the trunk on the current frame and attends to the cached demo keys/values, predicting a chunk of
targets; `select_action` makes one such query every `action_chunk` (5) control steps.
"""

import argparse
import statistics
import time

import torch

from mosaic_data.constants import CAMERA_KEY, STATE_DIM, STATE_KEY
from pipelines.bench.policy_train_step import paper_config, peak_rss_gib


def measure(threads: int, calls: int, layers: int, height: int, width: int) -> None:
    from mosaic_policy.mosaic.modeling_mosaic import MosaicPolicy

    torch.set_num_threads(threads)
    policy = MosaicPolicy(paper_config(height, width, n_attention_layers=layers)).eval()
    video = torch.randint(0, 256, (80, height, width, 3), dtype=torch.uint8)
    start = time.perf_counter()
    policy.set_demo(video)
    set_demo_ms = (time.perf_counter() - start) * 1e3
    observation = {CAMERA_KEY: torch.rand(1, 3, height, width), STATE_KEY: torch.randn(1, STATE_DIM)}
    with torch.inference_mode():
        for _ in range(10):
            policy.predict_action_chunk(observation)
        times, cpu_times = [], []
        for _ in range(calls):  # one policy query (select_action runs one per action_chunk control steps)
            start, cpu_start = time.perf_counter(), time.thread_time()
            policy.predict_action_chunk(observation)
            times.append((time.perf_counter() - start) * 1e3)
            cpu_times.append((time.thread_time() - cpu_start) * 1e3)
    times.sort()
    # With one thread, the calling thread's CPU time is the work itself, whatever else shares the cores.
    cpu_note = f", CPU time median {statistics.median(cpu_times):.1f} ms" if threads == 1 else ""
    print(
        f"{threads} thread(s), {layers} layers: one query median {statistics.median(times):.1f} ms, "
        f"p90 {times[int(0.9 * len(times))]:.1f} ms, min {times[0]:.1f} ms over {calls} calls; "
        f"set_demo once {set_demo_ms:.0f} ms{cpu_note}"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calls", type=int, default=100)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--layers", type=int, nargs="+", default=[2, 3])
    parser.add_argument("--height", type=int, default=100)
    parser.add_argument("--width", type=int, default=180)
    args = parser.parse_args()
    for threads in args.threads:
        for layers in args.layers:
            measure(threads, args.calls, layers, args.height, args.width)
    print(f"peak resident memory: {peak_rss_gib():.2f} GiB")


if __name__ == "__main__":
    main()
