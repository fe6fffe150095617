"""Published numbers of the MOSAIC paper (Mandi et al., "Towards More Generalizable One-shot Visual Imitation
Learning", ICRA 2022, arXiv 2110.13423): one-shot success in percent, as printed in the paper.

These are data from the paper, never results of this toolkit; reports print them beside our numbers and label
them "paper". On record: every cell of Table I, MOSAIC's columns of Table II and the appendix's single-task
ablations. A cell the paper has no number for (this project's own ablation rows, the data fractions that the paper
only plots, pick_place in Table II) is reported as "n/r" (not reported) rather than guessed. Adding a number means
copying it from the paper's table, with the table named in :data:`SOURCES`.
"""

from __future__ import annotations

TABLE_I: dict[tuple[str, str], dict[str, float]] = {
    ("single-task", "mosaic"): {"door": 67.1, "drawer": 65.4, "press_button": 71.7, "pick_place": 88.5, "stack_block": 79.3, "basketball": 67.5, "nut_assembly": 55.2},
    ("single-task", "mlp_osil"): {"door": 41.2, "drawer": 57.9, "press_button": 40.0, "pick_place": 12.8, "stack_block": 52.5, "basketball": 24.2, "nut_assembly": 15.6},
    ("single-task", "lstm_osil"): {"door": 65.8, "drawer": 57.5, "press_button": 48.3, "pick_place": 10.6, "stack_block": 8.6, "basketball": 5.4, "nut_assembly": 3.9},
    ("single-task", "tosil"): {"door": 57.9, "drawer": 57.5, "press_button": 56.4, "pick_place": 74.4, "stack_block": 13.3, "basketball": 12.5, "nut_assembly": 6.3},
    ("single-task", "daml"): {"door": 23.3, "drawer": 15.4, "press_button": 62.8, "pick_place": 0.0, "stack_block": 10.0, "basketball": 0.4, "nut_assembly": 2.2},
    ("multi-task", "mosaic"): {"door": 68.3, "drawer": 55.8, "press_button": 69.4, "pick_place": 42.1, "stack_block": 70.6, "basketball": 49.7, "nut_assembly": 30.7},
    ("multi-task", "mlp_osil"): {"door": 58.8, "drawer": 52.5, "press_button": 25.0, "pick_place": 5.0, "stack_block": 16.7, "basketball": 10.0, "nut_assembly": 6.7},
    ("multi-task", "lstm_osil"): {"door": 43.8, "drawer": 28.7, "press_button": 25.8, "pick_place": 2.2, "stack_block": 33.3, "basketball": 12.1, "nut_assembly": 4.4},
    ("multi-task", "tosil"): {"door": 49.2, "drawer": 53.3, "press_button": 63.3, "pick_place": 19.5, "stack_block": 34.4, "basketball": 6.9, "nut_assembly": 6.3},
    ("multi-task", "daml"): {"door": 10.8, "drawer": 3.3, "press_button": 1.7, "pick_place": 0.0, "stack_block": 0.0, "basketball": 0.0, "nut_assembly": 0.0},
}
"""(setting, method) -> task -> success %: every cell of Table I."""

TABLE_II: dict[str, dict[str, float]] = {
    "novel-task": {"door": 5.0, "drawer": 15.0, "press_button": 5.0, "stack_block": 0.0, "basketball": 0.0,
                   "nut_assembly": 0.0},
    "no-training": {"door": 2.5, "drawer": 1.2, "press_button": 0.0, "stack_block": 0.0, "basketball": 0.0,
                    "nut_assembly": 0.0},
    "fine-tune": {"door": 67.5, "drawer": 52.5, "press_button": 51.1, "stack_block": 98.3, "basketball": 72.8,
                  "nut_assembly": 73.3},
}
"""Column -> task -> success % of MOSAIC in Table II (pick_place is not in that table)."""

SINGLE_TASK_ABLATIONS: dict[str, dict[str, float]] = {
    "contrastive_off": {"door": 62.5, "drawer": 60.8, "press_button": 73.9, "pick_place": 69.5, "stack_block": 36.7,
                        "basketball": 19.7, "nut_assembly": 15.6},
    "positive_same": {"pick_place": 12.3, "basketball": 53.8, "nut_assembly": 12.2},
    "positive_fixed": {"pick_place": 80.2, "basketball": 52.5, "nut_assembly": 12.2},
    "contrastive_before": {"pick_place": 23.5, "basketball": 24.7, "nut_assembly": 17.8},
    "contrastive_after": {"pick_place": 51.5, "basketball": 27.2, "nut_assembly": 22.6},
}
"""Ablation variant of the ablations recipe -> task -> success % of the appendix's single-task ablations.

``contrastive_off`` is the appendix's "Single-task w/o Contra." row (its first ablation table); the positives and
placements are the second table's No-Temp (``positive_same``), Fix-Temp (``positive_fixed``), Pre-Attn
(``contrastive_before``) and Post-Attn (``contrastive_after``) columns, measured on three tasks only. The reference
row (``paper``) is Table I's single-task MOSAIC: the appendix's first table prints 71.1 and 88.8 for press_button
and pick_place where Table I prints 71.7 and 88.5. The appendix's multi-task rows (without contrast, BYOL) have no
row here because the ablations recipe trains single-task models."""

SOURCES = {
    "single-task": "paper, Table I (single-task)",
    "multi-task": "paper, Table I (multi-task)",
    "novel-task": "paper, Table II (Novel-task)",
    "fine-tune": "paper, Table II (Fine-tune)",
    "ablations": "paper, appendix ablation tables (single-task rows; the reference row from Table I)",
    "learning": "paper, Table I (single-task: every variation, the paper's training budget)",
}


def paper_number(table: str, row: str, task: str, fraction: int | None = None, mode: str | None = None) -> float | None:
    """The paper's success % for a cell of our tables, None when it is not on record here.

    A fine-tune cell has the paper's number only with all of the held-out task's data (``fraction`` 100 or None):
    fine-tuned, Table II's Fine-tune column; from scratch, that is the single-task setup of Table I."""
    if table in ("novel-task", "fine-tune") and row == "mosaic":
        if table == "fine-tune" and fraction not in (None, 100):
            return None
        if table == "fine-tune" and mode == "scratch":
            return TABLE_I[("single-task", "mosaic")].get(task)
        return TABLE_II[table].get(task)
    if table == "ablations" and row != "paper":
        return SINGLE_TASK_ABLATIONS.get(row, {}).get(task)
    if table == "ablations":  # the reference row: Table I's single-task MOSAIC
        table, row = "single-task", "mosaic"
    if table == "learning":  # one method trained on one task: the single-task setup of Table I
        table = "single-task"
    return TABLE_I.get((table, row), {}).get(task)
