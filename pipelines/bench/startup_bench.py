"""Start-up of the command lines and of the policy import: wall time, robosuite's warnings, heavy modules loaded.

    python -m pipelines.bench.startup_bench [--runs 7] [--dataset mosaic/door_panda [--output-dir DIR]]

Every row runs in fresh processes, as a user's command does (median and best of ``--runs``). "robosuite
lines" counts the ``[robosuite ...]`` lines on stderr; "heavy modules" lists which of torch, lerobot, robosuite
and cv2 the process had imported when it ended. ``--dataset`` adds ``mosaic-data validate DATASET`` (a
dataset made by ``mosaic-data collect``). The last row imports robosuite bare, for reference: the five warnings
robosuite prints on import, which ``mosaic_data`` filters (``mosaic_data.tasks.robosuite_log``).
Goals: ``mosaic-data --help`` and ``validate`` under 1 s, ``mosaic-eval --help`` under 1.5 s, on a 2-core CPU.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass

HEAVY_MODULES = ("torch", "lerobot", "robosuite", "cv2")

_REPORT_HEAVY = (
    "import atexit, sys\n"
    "atexit.register(lambda: print('HEAVY:' + ','.join(m for m in {heavy!r} if m in sys.modules), file=sys.stderr))\n"
)


@dataclass
class Row:
    label: str
    code: str
    """Python source the measured process runs (``python -c``): the entry point a console script calls."""


def _cli(module: str, args: list[str]) -> str:
    return f"import sys\nfrom {module} import main\nsys.exit(main({args!r}))\n"


def rows(dataset: str | None, output_dir: str | None) -> list[Row]:
    table = [
        Row("mosaic-data --help", _cli("mosaic_data.cli", ["--help"])),
        Row("mosaic-data tasks", _cli("mosaic_data.cli", ["tasks"])),
        Row("mosaic-eval --help", _cli("pipelines.evaluation.cli", ["--help"])),
        Row("import mosaic_policy", "import mosaic_policy\n"),
        Row("import lerobot_policy_mosaic (the plugin)", "import lerobot_policy_mosaic\n"),
        Row("import mosaic_data.tasks.base (simulator)", "import mosaic_data.tasks.base\n"),
        Row("import robosuite (bare, reference)", "import robosuite\n"),
    ]
    if dataset is not None:
        args = ["validate", dataset] + (["--output-dir", output_dir] if output_dir else [])
        table.insert(2, Row(f"mosaic-data validate {dataset}", _cli("mosaic_data.cli", args)))
    return table


@dataclass
class Figures:
    median_s: float
    best_s: float
    robosuite_lines: int
    heavy: str
    returncode: int


def measure(row: Row, runs: int) -> Figures:
    """Time ``runs`` fresh processes; one more reports the heavy modules (its atexit hook is not timed)."""
    command = [sys.executable, "-c", row.code]
    times = []
    stderr = ""
    returncode = 0
    for _ in range(runs):
        start = time.perf_counter()
        result = subprocess.run(command, capture_output=True, text=True)
        times.append(time.perf_counter() - start)
        stderr, returncode = result.stderr, result.returncode
    probe = subprocess.run([sys.executable, "-c", _REPORT_HEAVY.format(heavy=HEAVY_MODULES) + row.code], capture_output=True, text=True)
    heavy = next((line[len("HEAVY:"):] for line in probe.stderr.splitlines() if line.startswith("HEAVY:")), "?")
    robosuite_lines = sum(1 for line in stderr.splitlines() if "[robosuite" in line)
    return Figures(statistics.median(times), min(times), robosuite_lines, heavy or "-", returncode)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="timed runs per row")
    parser.add_argument("--dataset", default=None, help="a collected dataset (repo id or folder) for the validate row")
    parser.add_argument("--output-dir", default=None, help="where --dataset's repo id lives (mosaic-data's --output-dir)")
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{os.cpu_count()} CPUs, load average {load:.2f}; {args.runs} runs per row")
    print(f"{'command':<46} {'median s':>9} {'best s':>7} {'robosuite lines':>16}  heavy modules loaded")
    for row in rows(args.dataset, args.output_dir):
        figures = measure(row, args.runs)
        failed = f"  (exit {figures.returncode})" if figures.returncode not in (0,) else ""
        print(
            f"{row.label:<46} {figures.median_s:>9.2f} {figures.best_s:>7.2f} {figures.robosuite_lines:>16}  "
            f"{figures.heavy}{failed}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
