"""Benchmark of ``mosaic-eval`` with a policy: steps/s per worker and the demonstration's share, this tree against a
baseline commit, in the same run on this machine.

Prints figures (it asserts nothing). Both trees run the same command, one worker, alternately (``--repeats`` rounds,
the order flipped every round, so a noisy, shared machine weighs on both alike):

    mosaic-eval --policy.path CKPT --task door --variations 0,1 --episodes-per-variation 4 --workers 1

with ``PYTHONPATH`` set to the tree (each child prints which ``mosaic_data`` it imported; a wrong one stops the
benchmark). The baseline is a git worktree of ``--baseline-commit`` (made if missing). The checkpoint is an untrained
MOSAIC of the default size at 100x180, written by the baseline's code (an older configuration loads in a newer tree,
not always the other way round); untrained, it fails every episode, so every episode runs to the task's horizon.

Figures, from each run's results.json (per episode ``steps``, ``rollout_s`` = demonstration + reset + rollout,
``demo_s``, ``act_s``):

* steps/s per worker = steps / rollout time, over the episodes after the first of every variation (the first one
  also builds the demonstrator's scene for that variation), and over all episodes (what mosaic-eval prints);
* the demonstration's seconds per episode and its share of the rollout time; the policy's ms per step;
* the same per CPU second of the worker (``time.process_time`` around each episode and each demonstration, measured
  by wrapping ``RolloutWorker.run`` and ``ExpertDemoSource.demonstration`` in the child): a one-worker evaluation runs
  single-threaded, so this does not drop when other work shares the machine, as wall-clock figures do.

Usage: ``MUJOCO_GL=egl .venv/bin/python pipelines/bench/eval_bench.py`` (about 5 minutes at the defaults on 2 CPUs)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

CHECKPOINT_SCRIPT = """
import sys
from pipelines.evaluation.agents import untrained_mosaic
folder, height, width = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
for part in untrained_mosaic(height, width):
    part.save_pretrained(folder)
"""

EVAL_SCRIPT = """
import json, os, sys, time, mosaic_data
print("imported", mosaic_data.__file__, flush=True)
from pipelines.evaluation.cli import main
from pipelines.evaluation.demo_sources import ExpertDemoSource
from pipelines.evaluation.rollouts import RolloutWorker
cpu = {"demo": 0.0}
episodes = []
run, demonstration = RolloutWorker.run, ExpertDemoSource.demonstration
def timed_demonstration(self, *args, **kwargs):
    start = time.process_time()
    try:
        return demonstration(self, *args, **kwargs)
    finally:
        cpu["demo"] += time.process_time() - start
def timed_run(self, spec):
    cpu["demo"], start = 0.0, time.process_time()
    result = run(self, spec)
    episodes.append({"variation": spec.variation, "episode": spec.episode, "cpu_s": time.process_time() - start,
                     "demo_cpu_s": cpu["demo"]})
    return result
RolloutWorker.run, ExpertDemoSource.demonstration = timed_run, timed_demonstration
status = main(sys.argv[1:])
with open(os.environ["EVAL_BENCH_CPU"], "w") as file:
    json.dump(episodes, file)
sys.exit(status)
"""


def child_env(tree: Path) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(tree), MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    env.setdefault("HF_HUB_OFFLINE", "1")
    env.setdefault("WANDB_MODE", "disabled")
    return env


def run_in(tree: Path, script: str, arguments: list[str], workdir: Path, extra_env: dict | None = None) -> str:
    """Run ``script`` with ``tree`` first on the path, from a folder outside every tree (``python -c`` puts the
    working directory first on ``sys.path``)."""
    done = subprocess.run(
        [sys.executable, "-c", script, *arguments], cwd=workdir, env=child_env(tree) | (extra_env or {}),
        capture_output=True, text=True
    )
    if done.returncode != 0:
        raise SystemExit(f"{tree}: exit {done.returncode}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    return done.stdout


def baseline_tree(path: Path, commit: str) -> Path:
    if not path.exists():
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(path), commit], check=True,
                       capture_output=True)
    head = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], check=True, capture_output=True, text=True)
    wanted = subprocess.run(["git", "-C", str(REPO), "rev-parse", commit], check=True, capture_output=True, text=True)
    if head.stdout.strip() != wanted.stdout.strip():
        raise SystemExit(f"{path} is at {head.stdout.strip()[:7]}, not {commit}: remove it or pass --baseline-tree")
    return path


def figures(results: Path, cpu: Path) -> dict[str, float]:
    episodes = json.loads(results.read_text())["episodes"]
    cpu_of = {(c["variation"], c["episode"]): c for c in json.loads(cpu.read_text())}
    for e in episodes:
        e.update(cpu_of[(e["variation"], e["episode"])])
    firsts = {}
    for e in episodes:
        firsts.setdefault(e["variation"], e["episode"])
    steady = [e for e in episodes if e["episode"] != firsts[e["variation"]]] or episodes

    def rate(chosen: list[dict]) -> float:
        return sum(e["steps"] for e in chosen) / sum(e["rollout_s"] for e in chosen)

    return {
        "steps_per_s": rate(steady),
        "steps_per_cpu_s": sum(e["steps"] for e in steady) / sum(e["cpu_s"] for e in steady),
        "steps_per_s_all": rate(episodes),
        "demo_s": statistics.mean(e["demo_s"] for e in steady),
        "demo_cpu_s": statistics.mean(e["demo_cpu_s"] for e in steady),
        "demo_share": sum(e["demo_s"] for e in steady) / sum(e["rollout_s"] for e in steady),
        "act_ms": 1000 * sum(e["act_s"] for e in steady) / sum(e["steps"] for e in steady),
        "episodes": len(steady),
        "steps": sum(e["steps"] for e in steady),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--task", default="door")
    parser.add_argument("--variations", default="0,1", help="comma-separated")
    parser.add_argument("--episodes", type=int, default=4, help="per variation (the first of each is not measured)")
    parser.add_argument("--repeats", type=int, default=2, help="rounds of both trees, the order flipped every round")
    parser.add_argument("--seed", type=int, default=7000)
    parser.add_argument("--baseline-commit", default="a28e417")
    parser.add_argument("--baseline-tree", type=Path, default=Path("/tmp/mosaic_baseline"))
    parser.add_argument("--image-size", default="100x180", help="HxW of the policy's camera")
    args = parser.parse_args()
    trees = {"baseline": baseline_tree(args.baseline_tree, args.baseline_commit), "new": REPO}
    height, width = (int(v) for v in args.image_size.split("x"))
    runs: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
    with tempfile.TemporaryDirectory(prefix="mosaic_eval_bench_") as scratch:
        work = Path(scratch)
        checkpoint = work / "checkpoint"
        run_in(trees["baseline"], CHECKPOINT_SCRIPT, [str(checkpoint), str(height), str(width)], work)
        print(f"mosaic-eval --task {args.task} --variations {args.variations} --episodes-per-variation {args.episodes} "
              f"--workers 1, untrained MOSAIC (default size) at {height}x{width}, {os.cpu_count()} CPUs; baseline "
              f"{args.baseline_commit} ({trees['baseline']}) vs this tree ({REPO})", flush=True)
        for repeat in range(args.repeats):
            for name in (("baseline", "new") if repeat % 2 == 0 else ("new", "baseline")):
                output = work / f"{name}_{repeat}" / "results.json"
                stdout = run_in(trees[name], EVAL_SCRIPT, [
                    f"--policy.path={checkpoint}", "--task", args.task, "--variations", args.variations,
                    "--episodes-per-variation", str(args.episodes), "--workers", "1", "--seed", str(args.seed),
                    "--quiet", "--output", str(output),
                ], work, {"EVAL_BENCH_CPU": str(output.with_name("cpu.json"))})
                imported = Path(stdout.splitlines()[0].removeprefix("imported ").strip())
                if not imported.is_relative_to(trees[name]):
                    raise SystemExit(f"the {name} run imported {imported}, not {trees[name]}'s mosaic_data")
                run = figures(output, output.with_name("cpu.json"))
                runs[name].append(run)
                print(f"{name:8s} (mosaic_data from {imported.parent}): {run['steps_per_s']:5.2f} steps/s per worker "
                      f"({run['steps_per_s_all']:.2f} over all episodes, {run['steps_per_cpu_s']:.2f} per CPU second), demo {run['demo_s']:.2f} s/episode "
                      f"({100 * run['demo_share']:.1f}% of the rollout time), policy {run['act_ms']:.1f} ms/step, "
                      f"{run['steps']} steps in {run['episodes']} measured episodes", flush=True)

    def mean(name: str, key: str) -> float:
        return statistics.mean(run[key] for run in runs[name])

    print("\n| | baseline | new | new / baseline |")
    print("|---|---|---|---|")
    for label, key, scale, form in (
        ("steps/s per worker", "steps_per_s", 1, "{:.2f}"),
        ("steps/s per worker, all episodes", "steps_per_s_all", 1, "{:.2f}"),
        ("steps per CPU second (load-insensitive)", "steps_per_cpu_s", 1, "{:.2f}"),
        ("demo s per episode", "demo_s", 1, "{:.2f}"),
        ("demo CPU s per episode", "demo_cpu_s", 1, "{:.2f}"),
        ("demo share of rollout time, %", "demo_share", 100, "{:.1f}"),
        ("policy ms per step", "act_ms", 1, "{:.1f}"),
    ):
        old, new = scale * mean("baseline", key), scale * mean("new", key)
        print(f"| {label} | {form.format(old)} | {form.format(new)} | {new / old:.2f}x |")


if __name__ == "__main__":
    main()
