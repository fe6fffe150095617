"""The table cells of an experiment plan, read from the mosaic-eval results its evaluations wrote.

A table cell is one (method or variant, task): each training seed's success is the mean of its last
``eval_checkpoints`` checkpoints (each ``eval_episodes`` episodes per variation, on mosaic-eval's held-out
instances), and the cell is the mean +- std over seeds, then the 95% Wilson interval of that mean on the n
held-out instances behind it (:mod:`pipelines.evaluation.intervals`): every seed and checkpoint replays the same
instances, so n is one evaluation's episodes, not their sum; with 10 episodes per variation of a task of 4
variations (n=40) the interval still reaches 15 points either way. The interval is the episodes' uncertainty,
the "+-" the seeds' spread. The paper's published number stands beside it (:mod:`.paper_results`), None where
the paper reports none. Cells whose evaluations have not run yet count them in ``missing``: numbers come only from
runs. The report (:mod:`.report`) and the figures (:mod:`.figures`) read these records.
"""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipelines.evaluation.intervals import rate_interval

from .paper_results import paper_number
from .recipes import Evaluation, Plan


@dataclass
class CellResult:
    table: str
    row: str
    task: str
    fraction: int | None = None
    mode: str | None = None
    per_seed: dict[int, float] = field(default_factory=dict)
    episodes: int = 0  # of all its evaluations together
    successes: int = 0
    instances: int = 0  # distinct held-out episodes: every evaluation of the cell runs the same ones
    missing: int = 0  # planned evaluations without results yet
    confusion: list[list[int]] | None = None
    confusion_rows: list[int] | None = None
    confusion_columns: list[Any] | None = None
    wrong_variation_episodes: int = 0

    @property
    def mean(self) -> float | None:
        return float(np.mean(list(self.per_seed.values()))) if self.per_seed else None

    @property
    def std(self) -> float | None:
        return float(np.std(list(self.per_seed.values()))) if self.per_seed else None

    @property
    def interval(self) -> tuple[float, float] | None:
        """The 95% Wilson interval of ``mean`` on the cell's instances; None before any evaluation ran."""
        return rate_interval(self.mean, self.instances) if self.per_seed else None

    @property
    def paper(self) -> float | None:
        return paper_number(self.table, self.row, self.task, self.fraction, self.mode)

    def to_json(self) -> dict[str, Any]:
        return {
            "table": self.table, "row": self.row, "task": self.task, "fraction": self.fraction, "mode": self.mode,
            "success_per_seed": {str(seed): value for seed, value in sorted(self.per_seed.items())},
            "mean": self.mean, "std_over_seeds": self.std, "episodes": self.episodes, "successes": self.successes,
            "instances": self.instances, "ci95_low": None if self.interval is None else self.interval[0],
            "ci95_high": None if self.interval is None else self.interval[1],
            "missing_evaluations": self.missing, "paper": self.paper,
            "wrong_variation_share": self.wrong_variation_episodes / self.episodes if self.episodes else None,
            "confusion": None if self.confusion is None else {
                "rows": self.confusion_rows, "columns": self.confusion_columns, "counts": self.confusion},
        }


def read_results_table(evaluation: Evaluation) -> dict[str, Any] | None:
    """The table of one mosaic-eval results.json (its only agent: the checkpoint), None before it ran."""
    if not evaluation.results.is_file():
        return None
    results = json.loads(evaluation.results.read_text())
    if results.get("partial"):  # an evaluation that stopped early: its stage reruns it, the report waits for it
        return None
    return next(iter(results["tables"].values()))


def read_evaluation(evaluation: Evaluation) -> dict[str, Any] | None:
    """The task row of one mosaic-eval results.json, None before it ran."""
    table = read_results_table(evaluation)
    if table is None:
        return None
    return next((row for row in table["per_task"] if row["task"] == evaluation.task), None)


def cells_of(plan: Plan) -> list[CellResult]:
    """Every table cell of a plan, from the final checkpoints' evaluations."""
    cells: dict[tuple, CellResult] = {}
    per_seed_checkpoints: dict[tuple, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    for evaluation in plan.evaluations:
        if not evaluation.final:
            continue
        key = (evaluation.table, evaluation.row, evaluation.task, evaluation.fraction, evaluation.mode)
        cell = cells.setdefault(key, CellResult(*key))
        row = read_evaluation(evaluation)
        if row is None:
            cell.missing += 1
            continue
        per_seed_checkpoints[key][evaluation.seed].append(row["mean"])
        cell.episodes += row["episodes"]
        cell.successes += row["successes"]
        cell.instances = max(cell.instances, row.get("instances", row["episodes"]))  # no "instances": one checkpoint
        matrix = row["confusion"]
        counts = np.array(matrix["counts"])
        cell.confusion = (np.array(cell.confusion) + counts).tolist() if cell.confusion is not None else counts.tolist()
        cell.confusion_rows, cell.confusion_columns = matrix["rows"], matrix["columns"]
        cell.wrong_variation_episodes += round(matrix["wrong_variation_share"] * row["episodes"])
    for key, seeds in per_seed_checkpoints.items():
        cells[key].per_seed = {seed: float(np.mean(values)) for seed, values in seeds.items()}
    return list(cells.values())


def curves_of(plan: Plan) -> list[dict[str, Any]]:
    """Fine-tuning curves: one-shot success of every saved checkpoint, mean +- std over seeds, per run family."""
    points: dict[tuple, dict[int, dict[int, float]]] = defaultdict(lambda: defaultdict(dict))
    for evaluation in plan.evaluations:
        if evaluation.table != "fine-tune":
            continue
        row = read_evaluation(evaluation)
        if row is not None:
            key = (evaluation.task, evaluation.row, evaluation.mode, evaluation.fraction)
            points[key][evaluation.step][evaluation.seed] = row["mean"]
    # a fine-tuning curve starts from the model it fine-tunes: the novel-task model's own evaluation, at step 0
    for evaluation in plan.evaluations:
        if evaluation.table == "novel-task" and evaluation.final:
            row = read_evaluation(evaluation)
            for (task, method, mode, _), by_step in points.items():
                if row is not None and mode == "fine-tune" and (task, method) == (evaluation.task, evaluation.row):
                    by_step[0][evaluation.seed] = row["mean"]
    curves = []
    for (task, method, mode, fraction), by_step in sorted(points.items(), key=lambda item: str(item[0])):
        curves.append({
            "task": task, "method": method, "mode": mode, "fraction": fraction,
            "steps": sorted(by_step),
            "mean": [float(np.mean(list(by_step[s].values()))) for s in sorted(by_step)],
            "std": [float(np.std(list(by_step[s].values()))) for s in sorted(by_step)],
            "seeds": [len(by_step[s]) for s in sorted(by_step)],
        })
    return curves
