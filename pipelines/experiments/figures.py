"""PNG figures of an experiment report: per-task bars against the paper, fine-tuning and learning curves,
confusion matrices."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from .results import CellResult


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only: no display on a cluster or in CI
    import matplotlib.pyplot as plt

    return plt


def _save(plt, figure, path: Path) -> Path:
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
    return path


def plot_bars(cells: list[CellResult], table: str, path: Path) -> Path | None:
    """Grouped bars per task: each row's success (mean +- std over seeds) and, hatched, the paper's number."""
    chosen = [c for c in cells if c.table == table and c.mean is not None]
    if not chosen:
        return None
    plt = _pyplot()
    tasks = list(dict.fromkeys(c.task for c in chosen))
    rows = list(dict.fromkeys(c.row for c in chosen))
    by_key = {(c.row, c.task): c for c in chosen}
    width = 0.8 / (2 * len(rows))
    figure, axis = plt.subplots(figsize=(max(5.0, 1.6 * len(tasks) * max(1, len(rows) / 2)), 3.8), dpi=120)
    colours = plt.get_cmap("tab10")
    for index, row in enumerate(rows):
        offsets = np.arange(len(tasks)) + (2 * index) * width - 0.4 + width / 2
        ours = [by_key.get((row, t)) for t in tasks]
        bars = axis.bar(offsets, [100 * (c.mean or 0) if c else 0 for c in ours], width,
                        yerr=[100 * (c.std or 0) if c else 0 for c in ours], color=colours(index),
                        label=f"{row} (ours)", capsize=2)
        axis.bar_label(bars, fmt="%.0f", fontsize=6, padding=1)
        paper = [c.paper if c and c.paper is not None else np.nan for c in ours]
        if not all(np.isnan(paper)):
            axis.bar(offsets + width, paper, width, color="white", edgecolor=colours(index), hatch="//",
                     label=f"{row} (paper)")
    axis.set_xticks(np.arange(len(tasks)), tasks)
    axis.set(ylabel="one-shot success (%)", ylim=(0, 100), title=f"{table}: ours vs the paper")
    axis.grid(axis="y", alpha=0.3)
    axis.legend(fontsize=7, ncol=2)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
    return path


def plot_fine_tune(curves: list[dict[str, Any]], folder: Path) -> list[Path]:
    """One PNG per held-out task and method: success vs training steps, one line per data fraction, fine-tuning
    solid and training from scratch dashed (the paper's fine-tuning figure)."""
    plt = _pyplot()
    paths = []
    for task, method in dict.fromkeys((c["task"], c["method"]) for c in curves):
        mine = [c for c in curves if c["task"] == task and c["method"] == method]
        figure, axis = plt.subplots(figsize=(6, 3.8), dpi=120)
        fractions = sorted({c["fraction"] for c in mine})
        colours = plt.get_cmap("viridis")
        for curve in mine:
            colour = colours(fractions.index(curve["fraction"]) / max(1, len(fractions) - 1))
            mean, std = 100 * np.array(curve["mean"]), 100 * np.array(curve["std"])
            style, marker = ("-", "o") if curve["mode"] == "fine-tune" else ("--", "s")
            axis.plot(curve["steps"], mean, style, marker=marker, markersize=4, color=colour,
                      label=f"{curve['mode']}, {curve['fraction']}% data")
            axis.fill_between(curve["steps"], mean - std, mean + std, color=colour, alpha=0.12)
        axis.set(xlabel="training steps on the held-out task", ylabel="one-shot success (%)", ylim=(-3, 103))
        axis.set_title(f"{task} held out, {method}: fine-tuning vs training from scratch\n"
                       "(fine-tuning starts at step 0 from the model trained on the other tasks)", fontsize=9)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=7, ncol=2)
        paths.append(_save(plt, figure, folder / f"fine_tune_{task}_{method}.png"))
    return paths


def plot_learning_curves(curves: list[dict[str, Any]], folder: Path) -> list[Path]:
    """One PNG per run: success vs training steps with its interval band, the wrong-variation share, and each
    variation's success dotted."""
    from matplotlib.ticker import MaxNLocator

    plt = _pyplot()
    paths = []
    for curve in curves:
        points = curve["points"]
        if not points:
            continue
        steps = [p["step"] for p in points]
        figure, axis = plt.subplots(figsize=(6, 3.8), dpi=120)
        success = [100 * p["success"] for p in points]
        axis.plot(steps, success, "o-", color="tab:blue", label="one-shot success")
        axis.fill_between(steps, [100 * p["ci95"][0] for p in points], [100 * p["ci95"][1] for p in points],
                          color="tab:blue", alpha=0.15, label="95% interval")
        axis.plot(steps, [100 * p["wrong_variation_share"] for p in points], "s--", color="tab:red",
                  label="did another variation")
        colours = plt.get_cmap("Dark2")
        for index, variation in enumerate(points[-1]["per_variation"]):
            axis.plot(steps, [100 * p["per_variation"].get(variation, 0.0) for p in points], ":", alpha=0.8,
                      color=colours(index % 8), label=f"variation {variation}")
        axis.xaxis.set_major_locator(MaxNLocator(integer=True))
        axis.set(xlabel="training steps", ylabel="% of episodes", ylim=(-3, 103),
                 title=f"{curve['task']}, {curve['method']}: one-shot success vs training steps")
        axis.grid(alpha=0.3)
        axis.legend(fontsize=7, loc="best")
        paths.append(_save(plt, figure, folder / f"learning_{curve['task']}_{curve['method']}.png"))
    return paths


def plot_confusion(cell: CellResult, path: Path) -> Path:
    """The cell's confusion matrix summed over its seeds and checkpoints (mosaic-eval's heat map)."""
    from pipelines.evaluation.confusion import heat_map_figure

    plt = _pyplot()
    matrix = {"rows": cell.confusion_rows, "columns": cell.confusion_columns, "counts": cell.confusion,
              "wrong_variation_share": cell.wrong_variation_episodes / max(1, cell.episodes)}
    label = f"{cell.table} {cell.row}" + (f" ({cell.mode}, {cell.fraction}%)" if cell.fraction else "")
    figure = heat_map_figure(cell.task, label, [label], matrix)
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)
    return path
