"""Cost of one rendered frame: frame-sized render buffers against MuJoCo's defaults, in the same run.

    MUJOCO_GL=egl python pipelines/bench/render_bench.py [--tasks door,pick_place] [--frames 200] [--rounds 5]

For each task, two scenes of the same instance are built in this process: one as the suite builds it (offscreen
buffer at the frame size, no shadow map while shadows are off) and one with MuJoCo's default buffers (640x480,
4x multisampled, and a 4096x4096 shadow map: what every scene had before). Prints per task:

* milliseconds per 100x180 agentview frame (render + read-back + flip), the two scenes taking turns in
  ``--rounds`` blocks of ``--frames`` frames so that both see the same load on a shared machine; median of
  the blocks and the same-run ratio;
* resident memory of a fresh process that imported the suite, built the scene and rendered one frame, for each
  kind of buffer (separate processes: memory freed inside one process is not handed back, so deltas there lie);
* whether the two scenes' frames are identical.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

import mosaic_data.tasks.rendering as task_rendering  # noqa: E402
from mosaic_data.tasks import TASKS, make_task_env  # noqa: E402


def resident_mb() -> float:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def build(task: str, default_buffers: bool):
    """A scene of ``task`` built as the suite builds it, or with MuJoCo's default render buffers."""
    sizing = task_rendering.size_render_buffers
    if default_buffers:
        task_rendering.size_render_buffers = lambda xml, *args, **kwargs: xml
    try:
        env = make_task_env(task, 0, "panda")
    finally:
        task_rendering.size_render_buffers = sizing
    env.reset_to_seed(7)
    env.render_agentview()
    return env


def scene_process_mb(task: str, default_buffers: bool) -> float:
    """Resident MB of a fresh process after importing the suite, building one scene and rendering a frame."""
    code = (
        "import sys; sys.path.insert(0, '.'); from pipelines.bench import render_bench as b; "
        f"b.build({task!r}, {default_buffers}); print(b.resident_mb())"
    )
    output = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return float(output.strip().splitlines()[-1])


def ms_per_frame(env, frames: int) -> float:
    start = time.perf_counter()
    for _ in range(frames):
        env.render_agentview()
    return (time.perf_counter() - start) / frames * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--frames", type=int, default=100, help="frames per timed block")
    parser.add_argument("--rounds", type=int, default=5, help="timed blocks per scene, taking turns")
    args = parser.parse_args()
    print(f"render threads (LP_NUM_THREADS): {os.environ.get('LP_NUM_THREADS', 'Mesa default')}, MUJOCO_GL={os.environ['MUJOCO_GL']}")
    print(f"{'task':<14}{'frame-sized ms':>15}{'default ms':>12}{'ratio':>8}{'process MB new':>16}{'default':>9}  frames")
    for task in args.tasks.split(","):
        old_mb, new_mb = scene_process_mb(task, True), scene_process_mb(task, False)
        old, new = build(task, default_buffers=True), build(task, default_buffers=False)
        try:
            same = np.array_equal(old.render_agentview(), new.render_agentview())
            new_ms, old_ms = [], []
            for _ in range(args.rounds):
                new_ms.append(ms_per_frame(new, args.frames))
                old_ms.append(ms_per_frame(old, args.frames))
            new_median, old_median = statistics.median(new_ms), statistics.median(old_ms)
            print(
                f"{task:<14}{new_median:>15.2f}{old_median:>12.2f}{new_median / old_median:>7.2f}x"
                f"{new_mb:>16.0f}{old_mb:>9.0f}  {'identical' if same else 'DIFFERENT'}",
                flush=True,
            )
        finally:
            old.close()
            new.close()


if __name__ == "__main__":
    main()
