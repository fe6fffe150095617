"""results.md, results.json and PNG figures of an experiment folder, from the table cells of its plans
(:mod:`.results`): Markdown tables with ours beside the paper's published number, labelled "paper" ("n/r" where
the paper reports none), the figures, and the cells as JSON.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mosaic_data.atomic_files import write_bytes_atomically, write_json_atomically
from mosaic_data.constants import POLICY_TYPES
from pipelines.evaluation.intervals import interval_text

from .paper_results import SOURCES
from .presets import ExperimentPreset
from .recipes import ABLATIONS, Plan
from .results import CellResult, cells_of, curves_of

TABLE_TITLES = {
    "single-task": "Table I, single-task: trained and evaluated on each task",
    "multi-task": "Table I, multi-task: one model on all tasks, evaluated per task",
    "novel-task": "Table II, Novel-task: trained on the other tasks, one-shot on the held-out task",
    "fine-tune": "Table II, Fine-tune: the novel-task model fine-tuned on all of the held-out task's data",
    "ablations": "Appendix ablations: MOSAIC with one option changed",
    "learning": "Learning run: one method trained on the task, its last checkpoint(s)",
}


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f}"


def cell_text(cell: CellResult | None) -> str:
    """``"25.0 +- 5.0 [14.2, 40.2] (n=40) (paper 67.1)"``: mean +- std over seeds, the 95% interval on the n
    held-out instances; what is missing says so."""
    if cell is None:
        return "-"
    to_go = f"{cell.missing} evaluation{'s' if cell.missing != 1 else ''} to go"
    if cell.mean is None:
        ours = f"not run ({to_go})"
    else:
        ours = f"{_percent(cell.mean)} +- {_percent(cell.std)} {interval_text(cell.interval, cell.instances)}"
        if cell.missing:
            ours += f" ({to_go})"
    paper = "n/r" if cell.paper is None else f"{cell.paper:.1f}"
    return f"{ours} (paper {paper})"


def _row_name(table: str, row: str) -> str:
    if table == "ablations":
        group, _ = ABLATIONS[row]
        return f"{row} ({group})"
    return POLICY_TYPES.get(row, row)


def markdown_table(cells: list[CellResult], table: str, fraction: int | None = None, mode: str | None = None) -> str:
    chosen = [c for c in cells if c.table == table and c.fraction == fraction and c.mode == mode]
    tasks = list(dict.fromkeys(c.task for c in chosen))
    rows = list(dict.fromkeys(c.row for c in chosen))
    by_key = {(c.row, c.task): c for c in chosen}
    lines = ["| | " + " | ".join(tasks) + " |", "|---|" + "---|" * len(tasks)]
    for row in rows:
        lines.append(f"| {_row_name(table, row)} | " + " | ".join(cell_text(by_key.get((row, t))) for t in tasks) + " |")
    return "\n".join(lines) + "\n"


def fraction_table(cells: list[CellResult]) -> str:
    """Rows: method, mode and data fraction; columns: held-out tasks."""
    chosen = sorted((c for c in cells if c.table == "fine-tune"), key=lambda c: (c.row, c.fraction, c.mode != "fine-tune"))
    tasks = list(dict.fromkeys(c.task for c in chosen))
    rows = list(dict.fromkeys((c.row, c.mode, c.fraction) for c in chosen))
    by_key = {(c.row, c.mode, c.fraction, c.task): c for c in chosen}
    lines = ["| | " + " | ".join(tasks) + " |", "|---|" + "---|" * len(tasks)]
    for row, mode, fraction in rows:
        name = f"{POLICY_TYPES.get(row, row)}, {'fine-tuned' if mode == 'fine-tune' else 'from scratch'}, {fraction}% data"
        lines.append(f"| {name} | " + " | ".join(cell_text(by_key.get((row, mode, fraction, t))) for t in tasks) + " |")
    return "\n".join(lines) + "\n"


def wrong_variation_table(cells: list[CellResult]) -> str:
    lines = ["| table | row | task | episodes | one-shot success | did another variation | confusion |",
             "|---|---|---|---|---|---|---|"]
    for cell in cells:
        if cell.episodes:
            share = cell.wrong_variation_episodes / cell.episodes
            label = cell.row + (f", {cell.mode} {cell.fraction}%" if cell.fraction else "")
            success = f"{_percent(cell.mean)}% {interval_text(cell.interval, cell.instances)}"
            lines.append(f"| {cell.table} | {label} | {cell.task} | {cell.episodes} | {success} | "
                         f"{100 * share:.0f}% | [png](figures/{confusion_name(cell)}) |")
    return "\n".join(lines) + "\n"


def confusion_name(cell: CellResult) -> str:
    suffix = f"_{cell.mode}{cell.fraction}" if cell.fraction else ""
    return f"confusion_{cell.table}_{cell.row}_{cell.task}{suffix}.png"


def settings_text(preset_name: str, preset: ExperimentPreset, overrides: list[str]) -> str:
    p = preset
    text = (f"Preset `{preset_name}`: {p.image_size} images, {p.episodes} episodes per variation and robot, "
            f"{p.steps} training steps at batch {p.batch_size} ({p.train_obs_frames} observation frames), "
            f"{p.seeds} training seed(s); each seed's number is the mean of its last {p.eval_checkpoints} "
            f"checkpoint(s) x {p.eval_episodes} one-shot episode(s) per variation on held-out instances")
    if p.eval_max_steps:
        text += f", episodes capped at {p.eval_max_steps} steps"
    text += "."
    if p.train_options:
        text += f" lerobot-train options of every run: `{' '.join(p.train_options)}`."
    if p.mosaic_options:
        text += f" Of MOSAIC's runs (not the ablations' rows): `{' '.join(p.mosaic_options)}`."
    if overrides:
        text += " Overrides: " + ", ".join(f"`{o}`" for o in overrides) + "."
    return text


def write_report(output_dir: Path, entries: list[dict[str, Any]]) -> dict[str, Path]:
    """Write DIR/results.md, DIR/results.json and DIR/figures/*.png for the recipes run in DIR.

    ``entries``: per recipe run in the folder, {"recipe", "preset_name", "preset", "overrides", "plan",
    "seconds"} (seconds per stage kind, from the stages' done markers)."""
    from .figures import plot_bars, plot_confusion, plot_fine_tune, plot_learning_curves
    from .learning_report import learning_curves, per_variation_markdown

    figures_dir = output_dir / "figures"
    figures_dir.mkdir(parents=True, exist_ok=True)
    lines = ["# mosaic-experiment: one-shot success (%)\n",
             "Cells: ours, mean +- std over training seeds and [95% Wilson interval] on the n held-out episodes "
             "that every seed and checkpoint replays, then the paper's published number (paper); "
             "n/r: the paper reports no number for this cell. Numbers come only from runs in this folder. "
             "The interval is how well the episodes pin the rate down; the +- is the spread between seeds.\n"]
    summary: dict[str, Any] = {"recipes": []}
    for entry in entries:
        plan: Plan = entry["plan"]
        cells, curves = cells_of(plan), curves_of(plan)
        table = plan.recipe
        lines.append(f"\n## {plan.recipe}\n\n{settings_text(entry['preset_name'], entry['preset'], entry['overrides'])}\n")
        time_text = ", ".join(f"{kind} {seconds / 60:.1f} min" for kind, seconds in entry["seconds"].items() if seconds)
        if time_text:
            lines.append(f"\nTime of the finished stages on this machine: {time_text}.\n")
        if table == "fine-tune":
            top = max(entry["preset"].fine_tune_fractions)
            title = TABLE_TITLES["fine-tune"] if top == 100 else f"Table II, Fine-tune, with {top}% of the held-out task's data"
            lines.append(f"\n### {TABLE_TITLES['novel-task']}\n\n" + markdown_table(cells, "novel-task"))
            lines.append(f"\n### {title}\n\n" + markdown_table(cells, "fine-tune", top, "fine-tune"))
            lines.append("\n### By data fraction: fine-tuning against training from scratch (last checkpoints)\n\n")
            lines.append(fraction_table(cells))
            for path in plot_fine_tune(curves, figures_dir):
                lines.append(f"\n![fine-tuning curve](figures/{path.name})\n")
        else:
            lines.append(f"\n### {TABLE_TITLES[table]}\n\n")
            lines.append(markdown_table(cells, table))
        if table == "learning":
            curves = learning_curves(plan)
            lines.append("\n### Learning curve: every saved checkpoint, per variation (%)\n")
            lines.append(per_variation_markdown(curves))
            for path in plot_learning_curves(curves, figures_dir):
                lines.append(f"\n![learning curve](figures/{path.name})\n")
        elif table != "fine-tune":
            bars = plot_bars(cells, table, figures_dir / f"bars_{table}.png")
            if bars:
                lines.append(f"\n![{table} against the paper](figures/{bars.name})\n")
        lines.append(f"\nPaper numbers: {SOURCES[table]}.\n\n### Which variation the agent did\n\n")
        lines.append(wrong_variation_table(cells))
        for cell in cells:
            if cell.confusion is not None:
                plot_confusion(cell, figures_dir / confusion_name(cell))
        summary["recipes"].append({
            "recipe": plan.recipe, "preset": entry["preset_name"], "settings": entry["preset"].to_json(),
            "overrides": entry["overrides"], "seconds": entry["seconds"],
            "cells": [cell.to_json() for cell in cells], "curves": curves,
            "paper_source": SOURCES[table],
        })
    markdown_path, json_path = output_dir / "results.md", output_dir / "results.json"
    write_bytes_atomically(markdown_path, "".join(lines).encode())
    write_json_atomically(json_path, summary)
    return {"markdown": markdown_path, "json": json_path, "figures": figures_dir}
