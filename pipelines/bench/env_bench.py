"""Environment speed: control steps/s of every task, both robots, with and without rendering the camera.

    python -m pipelines.bench.env_bench [--tasks door,drawer] [--steps 100] [--slow-render]

The expert drives the robot so that contacts and motion are realistic. "render" renders one 100x180
agentview frame per step, as recording does; ``--slow-render`` also renders with MuJoCo's shadows,
reflections and skybox on and robosuite's full-detail visual meshes, to show what the fast settings save.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from mosaic_data.experts import make_expert  # noqa: E402
from mosaic_data.tasks import TASKS, make_task_env  # noqa: E402


def steps_per_second(task: str, robot: str, steps: int, render: bool, fast_render: bool) -> float:
    env = make_task_env(task, 0, robot, fast_render=fast_render, **({} if fast_render else {"visual_face_budget": None}))
    try:
        env.reset_to_seed(0)
        expert = make_expert(env)
        env.render_agentview()  # warm the renderer up outside the timing
        start = time.perf_counter()
        for step in range(steps):
            env.step(expert.act())
            if render:
                env.render_agentview()
            if step % env.horizon == env.horizon - 1:
                env.reset_to_seed(step)
                expert.reset()
        return steps / (time.perf_counter() - start)
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--slow-render", action="store_true", help="also measure with shadows/reflections on")
    args = parser.parse_args()
    print(f"{'task':<14}{'robot':<8}{'no render':>12}{'render':>10}" + (f"{'render (full)':>15}" if args.slow_render else ""))
    for task in args.tasks.split(","):
        for robot in ("panda", "sawyer"):
            bare = steps_per_second(task, robot, args.steps, render=False, fast_render=True)
            rendered = steps_per_second(task, robot, args.steps, render=True, fast_render=True)
            line = f"{task:<14}{robot:<8}{bare:>12.1f}{rendered:>10.1f}"
            if args.slow_render:
                line += f"{steps_per_second(task, robot, args.steps, render=True, fast_render=False):>15.1f}"
            print(line + "   steps/s", flush=True)


if __name__ == "__main__":
    main()
