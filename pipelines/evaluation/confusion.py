"""Which variation did the agent do? A confusion matrix per agent and task: rows = the variation demonstrated (the
one evaluated), columns = the variation whose goal the agent reached (see :class:`.rollouts.GoalTracker`), and a
last column "none". A policy that follows the demonstration fills the diagonal; one that ignores it fills one
column (it does the same variation whatever it is shown); one that does nothing fills "none".

An agent with several checkpoints (seeds of one recipe, like the success table's mean +- std) gets one matrix:
the sum over its checkpoints, so each row counts all its episodes; results.json also keeps each checkpoint's own
counts. Written to results.json (per task, next to its success rate), results.md, and one heat map PNG per task
and agent beside results.json.
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import numpy as np

from mosaic_data.tasks import get_task_class

from .rollouts import EpisodeResult

NONE_COLUMN = "none"


def confusion_matrix(results: list[EpisodeResult], checkpoints: dict[int, str]) -> dict[str, Any]:
    """Counts for the episodes of one agent on one task. Columns cover every variation of the task, also those
    not evaluated: an agent may well do a variation it was never shown."""
    task = results[0].task
    n_variations = len(get_task_class(task).variations)
    rows = sorted({r.variation for r in results})
    counts = _counts(results, rows, n_variations)
    wrong = sum(r.achieved_variation not in (None, r.variation) for r in results)
    matrix = {
        "rows": rows,
        "columns": [*range(n_variations), NONE_COLUMN],
        "counts": counts.tolist(),
        "wrong_variation_share": wrong / len(results),
    }
    if len(checkpoints) > 1:
        matrix["per_checkpoint"] = {
            label: _counts([r for r in results if r.agent_index == index], rows, n_variations).tolist()
            for index, label in checkpoints.items()
        }
    return matrix


def _counts(results: list[EpisodeResult], rows: list[int], n_variations: int) -> np.ndarray:
    counts = np.zeros((len(rows), n_variations + 1), dtype=int)
    for result in results:
        column = n_variations if result.achieved_variation is None else result.achieved_variation
        counts[rows.index(result.variation), column] += 1
    return counts


def descriptions(task: str) -> list[str]:
    return [variation.description for variation in get_task_class(task).variations]


# ---------------------------------------------------------------------------------------------- text


def confusion_markdown(tables: dict[str, Any]) -> str:
    """One table per agent and task, variations by index, their descriptions listed under it."""
    lines = ["\n## Which variation was achieved\n\n"
             "Rows: the variation demonstrated (evaluated); columns: the variation whose goal the agent reached "
             "(its own on success, else the first other one reached, else none). Several checkpoints: summed.\n"]
    for agent, table in tables.items():
        for row in table["per_task"]:
            matrix = row["confusion"]
            columns = [str(c) for c in matrix["columns"]]
            lines.append(
                f"\n### {row['task']}: {agent}\n\n| demonstrated \\ achieved | " + " | ".join(columns) + " |\n"
                + "|---|" + "---|" * len(columns) + "\n"
            )
            for variation, counts in zip(matrix["rows"], matrix["counts"]):
                cells = [f"**{n}**" if column == variation else str(n) for column, n in zip(matrix["columns"], counts)]
                lines.append(f"| {variation} | " + " | ".join(cells) + " |\n")
            wrong = 100 * matrix["wrong_variation_share"]
            lines.append(f"\nWrong variation achieved in {wrong:.1f}% of episodes. Variations:\n\n")
            lines.extend(f"- {index}: {text}\n" for index, text in enumerate(descriptions(row["task"])))
    return "".join(lines)


def wrong_variation_text(task_row: dict[str, Any]) -> str:
    """The share of a task's episodes in which the agent did another variation than the one shown, in percent."""
    return f"{100 * task_row['confusion']['wrong_variation_share']:.1f}%"


# ---------------------------------------------------------------------------------------------- heat maps


def heat_map_path(folder: Path, task: str, agent: str, several_agents: bool) -> Path:
    """``confusion_<task>.png``, or ``confusion_<task>_<agent>.png`` when several agents were evaluated."""
    safe_agent = "".join(c if c.isalnum() or c in "-_." else "_" for c in agent)
    return Path(folder) / (f"confusion_{task}_{safe_agent}.png" if several_agents else f"confusion_{task}.png")


def write_heat_maps(folder: Path, tables: dict[str, Any]) -> list[Path]:
    """One PNG per agent and task beside results.json; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")  # files only, no display (and no GUI toolkit in a worker or on a cluster)
    import matplotlib.pyplot as plt

    paths = []
    for agent, table in tables.items():
        for row in table["per_task"]:
            path = heat_map_path(folder, row["task"], agent, len(tables) > 1)
            figure = heat_map_figure(row["task"], agent, table["checkpoints"], row["confusion"])
            path.parent.mkdir(parents=True, exist_ok=True)
            figure.savefig(path, dpi=110, bbox_inches="tight")
            plt.close(figure)
            paths.append(path)
    return paths


def heat_map_figure(task: str, agent: str, checkpoints: list[str], matrix: dict[str, Any]):
    """Cells coloured by the share of their row (rows may hold different episode counts), counts written in."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    counts = np.array(matrix["counts"])
    shares = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1)
    n_rows, n_columns = counts.shape
    figure, axes = plt.subplots(figsize=(2.2 + 0.6 * n_columns, 1.6 + 0.5 * n_rows))
    axes.imshow(shares, cmap="Blues", vmin=0.0, vmax=1.0, aspect="auto")
    for i in range(n_rows):
        for j in range(n_columns):
            axes.text(j, i, str(counts[i, j]), ha="center", va="center", fontsize=10,
                      color="white" if shares[i, j] > 0.55 else "black")
        diagonal = matrix["columns"].index(matrix["rows"][i])
        axes.add_patch(
            Rectangle((diagonal - 0.5, i - 0.5), 1, 1, fill=False, edgecolor="darkorange", linewidth=2, clip_on=False)
        )
    axes.axvline(n_columns - 1.5, color="grey", linewidth=1)  # "none" is not a variation
    axes.set_xticks(range(n_columns), [str(c) for c in matrix["columns"]])
    axes.set_yticks(range(n_rows), [str(r) for r in matrix["rows"]])
    axes.set_xlabel("variation achieved")
    axes.set_ylabel("variation demonstrated")
    subtitle = "" if checkpoints == [agent] else "\n" + _checkpoint_label(checkpoints)  # a baseline is its own label
    axes.set_title(f"{task}: {agent}{subtitle}", fontsize=10)
    legend = "\n".join(f"{index}: {text}" for index, text in enumerate(descriptions(task)))
    wrong = 100 * matrix["wrong_variation_share"]
    axes.annotate(
        f"orange: the demonstrated variation; wrong variation in {wrong:.0f}% of episodes\n{legend}",
        xy=(0, 0), xycoords="axes fraction", xytext=(0, -36), textcoords="offset points", va="top", fontsize=7,
    )
    return figure


def _checkpoint_label(checkpoints: list[str], width: int = 70) -> str:
    """The checkpoint(s) in at most two title lines (results.json has the full paths)."""
    if len(checkpoints) == 1 and len(checkpoints[0]) <= width:
        return checkpoints[0]
    names = [_short_name(label) for label in checkpoints]
    text = names[0] if len(names) == 1 else f"{len(names)} checkpoints, summed: " + ", ".join(names)
    lines = textwrap.wrap(text, width, break_long_words=False)
    return "\n".join(lines[:2]) + (" ..." if len(lines) > 2 else "")


def _short_name(label: str) -> str:
    """``outputs/train/door_seed1/checkpoints/last/pretrained_model`` -> ``door_seed1`` (``door_seed1@005000`` for
    a numbered checkpoint); other paths keep their last two parts."""
    parts = list(Path(label).parts)
    if parts and parts[-1] == "pretrained_model":
        parts.pop()
    if len(parts) >= 3 and parts[-2] == "checkpoints":
        return parts[-3] + ("" if parts[-1] == "last" else f"@{parts[-1]}")
    return "/".join(parts[-2:])
