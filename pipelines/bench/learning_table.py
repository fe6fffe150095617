"""Side by side: the one-shot results of several `policy_learning` runs (e.g. every policy of Table I on door).

    python -m pipelines.bench.learning_table outputs/learning/mosaic outputs/learning/tosil ... --png compare.png

Reads each run's results.json (its last checkpoint) and prints a Markdown table: policy, training steps, one-shot
success, how often another variation's goal was reached, per-variation success, and each run's confusion matrix
row by row; `--png` draws the success and wrong-variation shares as bars next to each other.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def load_run(folder: Path) -> dict:
    results_file = folder / "results.json"
    if not results_file.is_file():
        raise SystemExit(f"learning_table: {results_file} is missing: run pipelines.bench.policy_learning there first")
    results = json.loads(results_file.read_text())
    if not results.get("final"):
        raise SystemExit(f"learning_table: {results_file} holds no evaluated checkpoint")
    return results


def markdown(runs: list[dict]) -> str:
    variations = sorted({v for run in runs for v in run["final"]["per_variation"]}, key=int)
    header = "| policy | steps | one-shot success | wrong variation | " + " | ".join(f"var {v}" for v in variations) + " |"
    lines = [header, "|" + "---|" * (4 + len(variations))]
    for run in runs:
        final = run["final"]
        wrong = final["wrong_variation_share"] or 0.0
        cells = " | ".join(f"{100 * final['per_variation'].get(v, 0):.0f}%" for v in variations)
        lines.append(
            f"| {run.get('policy_type', 'mosaic')} | {final['step']} | {100 * final['success']:.0f}% | "
            f"{100 * wrong:.0f}% | {cells} |"
        )
    lines.append("")
    for run in runs:
        confusion = run["final"]["confusion"]
        lines.append(f"{run.get('policy_type', 'mosaic')}: demonstrated -> achieved (episodes) " + "; ".join(
            f"{row} -> " + ", ".join(f"{column}: {n}" for column, n in zip(confusion["columns"], counts, strict=True) if n)
            for row, counts in zip(confusion["rows"], confusion["counts"], strict=True)
        ))
    return "\n".join(lines)


def plot(runs: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = [run.get("policy_type", "mosaic") for run in runs]
    success = [100 * run["final"]["success"] for run in runs]
    wrong = [100 * (run["final"]["wrong_variation_share"] or 0) for run in runs]
    x = np.arange(len(runs))
    figure, axis = plt.subplots(figsize=(6.5, 3.6), dpi=120)
    axis.bar(x - 0.2, success, 0.4, label="one-shot success")
    axis.bar(x + 0.2, wrong, 0.4, label="another variation's goal reached")
    axis.set_xticks(x, names)
    axis.set(ylabel="% of episodes", ylim=(0, 100), title=title)
    axis.grid(axis="y", alpha=0.3)
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path, help="output folders of policy_learning runs")
    parser.add_argument("--png", type=Path, default=None, help="write the bar chart here")
    args = parser.parse_args(argv)
    runs = [load_run(folder) for folder in args.runs]
    print(markdown(runs))
    if args.png is not None:
        tasks = sorted({run["task"] for run in runs})
        plot(runs, args.png, f"{', '.join(tasks)}: one-shot success after the same training budget")
        print(f"bar chart: {args.png}")


if __name__ == "__main__":
    main()
