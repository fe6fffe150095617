"""Published numbers of the MOSAIC paper (Mandi et al., "Towards More Generalizable One-shot Visual Imitation
Learning", ICRA 2022, arXiv 2110.13423): one-shot success in percent, as printed in the paper.

These are data from the paper, never results of this toolkit; reports print them beside our numbers and label
them "paper". Only the cells listed here are on record; every other cell of the paper's tables is reported as
"n/r" (not recorded here) rather than guessed. Adding a number means copying it from the paper's table, with
the table named in :data:`SOURCES`.
"""

from __future__ import annotations

TABLE_I: dict[tuple[str, str], dict[str, float]] = {
    ("single-task", "mosaic"): {"door": 67.1, "drawer": 65.4, "press_button": 71.7, "pick_place": 88.5,
                                "stack_block": 79.3, "basketball": 67.5, "nut_assembly": 55.2},
    ("multi-task", "mosaic"): {"door": 68.3, "drawer": 55.8, "press_button": 69.4, "pick_place": 42.1,
                               "stack_block": 70.6, "basketball": 49.7, "nut_assembly": 30.7},
    ("multi-task", "tosil"): {"door": 49.2, "drawer": 53.3, "press_button": 63.3, "pick_place": 19.5,
                              "stack_block": 34.4, "basketball": 6.9, "nut_assembly": 6.3},
}
"""(setting, method) -> task -> success %."""

SOURCES = {
    "single-task": "paper, Table I (single-task)",
    "multi-task": "paper, Table I (multi-task)",
    "novel-task": "paper, Table II (No Training)",
    "fine-tune": "paper, Table II (Fine-tune)",
    "ablations": "paper, appendix ablation tables",
}


def paper_number(table: str, row: str, task: str) -> float | None:
    """The paper's success % for a cell of our tables, None when it is not on record here."""
    return TABLE_I.get((table, row), {}).get(task)
