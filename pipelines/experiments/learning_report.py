"""The ``learning`` recipe's part of a report: the learning curve of every run and its checkpoints' per-variation
success, which the Table-I style cells (one number per method and task) do not show (``figures.py`` draws it).

A learning run is judged by one-shot success on held-out instances, its interval, and which variation the agent
did; a curve point is one evaluated checkpoint, averaged over training seeds when there are several.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import numpy as np

from pipelines.evaluation.intervals import rate_interval

from .recipes import Evaluation, Plan
from .results import read_results_table


def _checkpoint_result(evaluation: Evaluation) -> dict[str, Any] | None:
    """Success, wrong-variation share and per-variation success of one evaluated checkpoint."""
    table = read_results_table(evaluation)
    task_row = None if table is None else next((r for r in table["per_task"] if r["task"] == evaluation.task), None)
    if task_row is None:
        return None
    return {
        "success": task_row["mean"],
        "episodes": task_row["episodes"],
        "wrong_variation_share": task_row["confusion"]["wrong_variation_share"] or 0.0,
        "per_variation": {int(row["variation"]): row["mean"] for row in table["per_variation"]
                          if row["task"] == evaluation.task},
        "descriptions": {int(row["variation"]): row["description"] for row in table["per_variation"]
                         if row["task"] == evaluation.task},
    }


def learning_curves(plan: Plan) -> list[dict[str, Any]]:
    """One curve per (task, method) of the plan's ``learning`` evaluations: per saved step, the success (mean over
    seeds) with its 95% Wilson interval on the held-out instances every seed replays, the wrong-variation share and
    per-variation success."""
    by_run: dict[tuple[str, str], dict[int, list[dict[str, Any]]]] = defaultdict(lambda: defaultdict(list))
    for evaluation in plan.evaluations:
        if evaluation.table != "learning":
            continue
        result = _checkpoint_result(evaluation)
        if result is not None:
            by_run[(evaluation.task, evaluation.row)][evaluation.step].append(result)
    curves = []
    for (task, method), by_step in sorted(by_run.items()):
        points = []
        for step in sorted(by_step):
            results = by_step[step]
            success = float(np.mean([r["success"] for r in results]))
            episodes = max(r["episodes"] for r in results)  # every seed replays the same held-out instances
            low, high = rate_interval(success, episodes)
            variations = sorted({v for r in results for v in r["per_variation"]})
            points.append({
                "step": step,
                "success": success,
                "ci95": [low, high],
                "episodes": episodes,
                "seeds": len(results),
                "wrong_variation_share": float(np.mean([r["wrong_variation_share"] for r in results])),
                "per_variation": {str(v): float(np.mean([r["per_variation"][v] for r in results if v in r["per_variation"]]))
                                  for v in variations},
                "descriptions": {str(v): d for r in results for v, d in r["descriptions"].items()},
            })
        curves.append({"task": task, "method": method, "points": points})
    return curves


def per_variation_markdown(curves: list[dict[str, Any]]) -> str:
    """Per run: success of each variation at every evaluated checkpoint."""
    lines = []
    for curve in curves:
        points = curve["points"]
        if not points:
            continue
        variations = list(points[-1]["per_variation"])
        lines.append(f"\n{curve['task']}, {curve['method']}:\n\n")
        lines.append("| step | one-shot success [95% CI] | did another variation | "
                     + " | ".join(f"{v}: {points[-1]['descriptions'].get(v, '')}" for v in variations) + " |\n")
        lines.append("|---|---|---|" + "---|" * len(variations) + "\n")
        for point in points:
            low, high = point["ci95"]
            lines.append(
                f"| {point['step']} | {100 * point['success']:.1f} [{100 * low:.1f}, {100 * high:.1f}] "
                f"(n={point['episodes']}) | {100 * point['wrong_variation_share']:.1f} | "
                + " | ".join(f"{100 * point['per_variation'].get(v, 0.0):.0f}" for v in variations) + " |\n"
            )
    return "".join(lines)
