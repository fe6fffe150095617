"""Where the scripted experts hold the hand still: the longest hold per task and robot, and the phase it is in.

    python -m pipelines.bench.expert_holds [--tasks door,drawer] [--seeds 3] [--variations all|sample]

A hold is a run of control steps whose position target moves less than 2.5 mm per step, outside an episode's
first 3 and last 10 steps (:func:`mosaic_data.collection.validate.longest_hold`). A policy sees one frame per
query: during a hold whose only change is one the frame barely shows (fingers closing in the air, a settle),
the next action is ambiguous from the image, and learned policies stall there. Prints, per task and robot,
the longest hold over the episodes with its phase, the mean longest hold, expert success and mean length.
"""

from __future__ import annotations

import argparse
import os
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("MUJOCO_GL", "egl")

from mosaic_data.collection.validate import longest_hold  # noqa: E402
from mosaic_data.tasks.spec import TASK_NAMES, TASK_SPECS  # noqa: E402

ROBOTS = ("panda", "sawyer")


def task_holds(task: str, robot: str, variations: list[int], seeds: list[int]) -> dict:
    """Run the expert on every (variation, seed) without rendering; the hold statistics of its episodes."""
    from mosaic_data.experts import make_expert
    from mosaic_data.tasks import make_task_env

    env = make_task_env(task, variations[0], robot)
    holds, phases, successes, lengths = [], Counter(), 0, []
    try:
        for variation in variations:
            env.set_variation(variation)
            for seed in seeds:
                env.reset_to_seed(seed)
                expert = make_expert(env)
                actions, phase_names = [], []
                for _ in range(env.horizon):
                    phase_names.append(expert.phase_name)
                    actions.append(expert.act())
                    env.step(actions[-1])
                    if env.check_success():
                        successes += 1
                        break
                length, start = longest_hold(actions)
                holds.append(length)
                lengths.append(len(actions))
                if length:
                    phases[phase_names[start]] += 1
    finally:
        env.close()
    longest = max(holds)
    return {
        "task": task, "robot": robot, "episodes": len(holds), "longest": longest,
        "mean_longest": sum(holds) / len(holds), "phases": dict(phases.most_common(3)),
        "success": successes / len(holds), "mean_length": sum(lengths) / len(lengths),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default=",".join(TASK_NAMES))
    parser.add_argument("--robots", default=",".join(ROBOTS))
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--variations", choices=("all", "sample"), default="sample",
                        help="all variations, or the first, a middle and the last one")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    jobs = []
    for task in args.tasks.split(","):
        count = len(TASK_SPECS[task].variations)
        variations = list(range(count)) if args.variations == "all" else sorted({0, count // 2, count - 1})
        for robot in args.robots.split(","):
            jobs.append((task, robot, variations, list(range(args.seeds))))
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(task_holds, *zip(*jobs)))
    print(f"{'task':<14}{'robot':<8}{'episodes':>9}{'longest':>9}{'mean':>7}{'success':>9}{'length':>8}  phase of the holds")
    for row in rows:
        phases = ", ".join(f"{name} x{count}" for name, count in row["phases"].items()) or "-"
        print(f"{row['task']:<14}{row['robot']:<8}{row['episodes']:>9}{row['longest']:>9}{row['mean_longest']:>7.1f}"
              f"{row['success']:>9.0%}{row['mean_length']:>8.1f}  {phases}")


if __name__ == "__main__":
    main()
