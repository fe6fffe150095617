"""Success tables of an evaluation, as the paper reports them: per variation and per task, mean +- std, and how
far the measured rate may be from the true one.

An *agent* is one row family: a set of checkpoints (e.g. the same recipe trained with several seeds), the
scripted expert, or the untrained policy. For each agent and variation the success rate is the mean over its
episodes; the "+-" is the standard deviation over episodes (of the 0/1 outcomes) and, when the agent has
several checkpoints, also over the checkpoints' own success rates. A task's rate is the mean over all its
episodes (every variation has the same number), with the same two deviations. Every cell also carries its
episodes, successes and distinct episodes (``instances``: an agent's checkpoints replay the same ones) and the
95% Wilson score interval of its rate on those instances (:mod:`.intervals`), shown as ``[low, high] (n=...)``:
how well the rate is known (on 10 episodes, up to 30 points either way), where the std of the 0/1 outcomes
gives the spread of single episodes. Each task row also carries its confusion matrix (which variation the agent
did, :mod:`.confusion`).
"""

from __future__ import annotations

import os
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mosaic_data.atomic_files import write_bytes_atomically, write_json_atomically
from mosaic_data.recording_files import check_folder_takes_file

from .options import EvaluationError
from .confusion import confusion_markdown, confusion_matrix, wrong_variation_text
from .intervals import interval_text, rate_interval
from .rollouts import EpisodeResult


@dataclass
class Cell:
    """Success of one agent on one group of episodes (a variation, a task, or everything). ``instances``: the
    distinct episodes among them (its checkpoints replay the same ones); ``ci95_low`` and ``ci95_high`` bound
    the 95% Wilson interval of ``mean`` measured on that many."""

    episodes: int
    successes: int
    mean: float
    std_episodes: float
    std_checkpoints: float | None
    per_checkpoint: list[float]
    instances: int
    ci95_low: float
    ci95_high: float


def _cell(results: list[EpisodeResult], checkpoints: dict[int, str]) -> Cell:
    outcomes = np.array([r.success for r in results], dtype=float)
    by_checkpoint: dict[int, list[bool]] = defaultdict(list)
    for result in results:
        by_checkpoint[result.agent_index].append(result.success)
    per_checkpoint = [float(np.mean(by_checkpoint[index])) for index in checkpoints if index in by_checkpoint]
    mean = float(outcomes.mean())
    instances = len({(r.task, r.variation, r.episode) for r in results})
    low, high = rate_interval(mean, instances)  # never None: summarize makes no cell without episodes
    return Cell(
        episodes=len(results),
        successes=int(outcomes.sum()),
        mean=mean,
        std_episodes=float(outcomes.std()),
        std_checkpoints=float(np.std(per_checkpoint)) if len(per_checkpoint) > 1 else None,
        per_checkpoint=per_checkpoint,
        instances=instances,
        ci95_low=low,
        ci95_high=high,
    )


def summarize(results: list[EpisodeResult], agent_groups: dict[str, dict[int, str]]) -> dict[str, Any]:
    """Tables keyed by agent name. ``agent_groups``: agent name -> {agent index: checkpoint label}."""
    tables: dict[str, Any] = {}
    for name, members in agent_groups.items():
        mine = [r for r in results if r.agent_index in members]
        per_variation, per_task = [], []
        for task in dict.fromkeys(r.task for r in mine):
            of_task = [r for r in mine if r.task == task]
            for variation in sorted({r.variation for r in of_task}):
                of_variation = [r for r in of_task if r.variation == variation]
                per_variation.append(
                    {"task": task, "variation": variation, "description": of_variation[0].description}
                    | _cell(of_variation, members).__dict__
                )
            per_task.append(
                {"task": task, "variations": len({r.variation for r in of_task})}
                | _cell(of_task, members).__dict__
                | {"confusion": confusion_matrix(of_task, members)}
            )
        tables[name] = {
            "checkpoints": list(members.values()),
            "per_variation": per_variation,
            "per_task": per_task,
            "overall": _cell(mine, members).__dict__ if mine else None,
        }
    return tables


def timing(results: list[EpisodeResult], wall_s: float, workers: int) -> dict[str, float]:
    """Throughput figures: control steps per second overall and per worker, and the policy's share."""
    steps = sum(r.steps for r in results)
    rollout_s = sum(r.rollout_s for r in results)
    act_s = sum(r.act_s for r in results)
    return {
        "wall_s": round(wall_s, 2),
        "workers": workers,
        "episodes": len(results),
        "steps": steps,
        "steps_per_s": round(steps / wall_s, 2) if wall_s > 0 else 0.0,
        "steps_per_s_per_worker": round(steps / rollout_s, 2) if rollout_s > 0 else 0.0,
        "act_ms_per_step": round(1000 * act_s / steps, 2) if steps else 0.0,
        "demo_s_per_episode": round(sum(r.demo_s for r in results) / len(results), 2) if results else 0.0,
    }


def _rows(tables: dict[str, Any], level: str) -> dict[tuple, dict[str, dict[str, Any] | None]]:
    """Rows of one level ("per_task" or "per_variation") in first-seen order, each agent's cell or None: agents of
    a partial evaluation may have finished different episodes."""
    rows: dict[tuple, dict[str, dict[str, Any] | None]] = {}
    for agent, table in tables.items():
        for cell in table[level]:
            key = (cell["task"], cell.get("variation"))
            rows.setdefault(key, dict.fromkeys(tables))[agent] = cell
    return rows


def markdown(tables: dict[str, Any], settings: dict[str, Any], partial: dict[str, Any] | None = None) -> str:
    """One table per task level: rows = variations (then tasks), columns = agents, cells = success % with its 95%
    interval and episodes."""
    agents = list(tables)
    header = "| | " + " | ".join(agents) + " |\n|---|" + "---|" * len(agents) + "\n"
    lines = [
        "# mosaic-eval: one-shot success (%), mean +- std [95% interval] (n distinct episodes) "
        f"({settings['episodes_per_variation']} episodes per variation)\n"
    ]
    if partial is not None:
        lines.append(
            f"\n**Partial results: {partial['finished']} of {partial['planned']} episodes finished** "
            f"({partial['reason']}).\n\n"
        )
    lines.append("## Per task\n\n" + header)
    for (task, _), cells in _rows(tables, "per_task").items():
        lines.append(f"| {task} | " + " | ".join(_cell_text(cells[a]) for a in agents) + " |\n")
    overall = [tables[a]["overall"] for a in agents]
    lines.append("| **all** | " + " | ".join(_cell_text(c) for c in overall) + " |\n")
    lines.append("\n## Per variation\n\n" + header)
    for (task, variation), cells in _rows(tables, "per_variation").items():
        description = next(cell["description"] for cell in cells.values() if cell is not None)
        lines.append(f"| {task} {variation}: {description} | " + " | ".join(_cell_text(cells[a]) for a in agents) + " |\n")
    lines.append(
        "\n+- is the standard deviation over checkpoints when an agent has several, else over episodes. "
        "[low, high] is the 95% Wilson score interval of the success rate on the cell's n distinct episodes (an "
        "agent's checkpoints replay the same ones): where two agents' intervals overlap, more episodes may be "
        "needed to rank them. "
        f"Seeds: base {settings['seed']}; demonstrations: {settings['demo_source']}.\n"
    )
    lines.append(confusion_markdown(tables))
    return "".join(lines)


def _cell_text(cell: dict[str, Any] | None) -> str:
    """``"70.0 +- 45.8 [48.1, 85.5] (n=20)"`` in percent: the checkpoint deviation when there is one, else the
    episodes', then the 95% interval and the distinct episodes behind the rate."""
    if cell is None:
        return "-"
    std = cell["std_checkpoints"] if cell["std_checkpoints"] is not None else cell["std_episodes"]
    interval = interval_text((cell["ci95_low"], cell["ci95_high"]), cell["instances"])
    return f"{100 * cell['mean']:.1f} +- {100 * std:.1f} {interval}"


TERMINAL_LEGEND = "one-shot success %: mean +- std [95% Wilson interval] (n distinct episodes)"


def print_table(tables: dict[str, Any]) -> str:
    """The per-task (and, for one task, per-variation) table as plain text for the terminal, under a line that
    says what its cells show, with the share of episodes per task in which the agent did another variation than
    the one demonstrated."""
    agents = list(tables)
    per_task = _rows(tables, "per_task")
    rows = [("", *agents)]
    if len(per_task) == 1:
        for (task, variation), cells in _rows(tables, "per_variation").items():
            rows.append((f"{task} {variation}", *(_cell_text(cells[a]) for a in agents)))
    for (task, _), cells in per_task.items():
        rows.append((f"{task} (all)", *(_cell_text(cells[a]) for a in agents)))
    for (task, _), cells in per_task.items():
        rows.append((f"{task} wrong variation", *(wrong_variation_text(cells[a]) if cells[a] else "-" for a in agents)))
    if len(per_task) > 1:
        rows.append(("all tasks", *(_cell_text(tables[a]["overall"]) for a in agents)))
    widths = [max(len(str(row[i])) for row in rows) for i in range(len(rows[0]))]
    table = ("  ".join(str(cell).ljust(width) for cell, width in zip(row, widths)) for row in rows)
    return "\n".join([TERMINAL_LEGEND, *table])


def report_paths(path: Path) -> tuple[Path, Path]:
    """The JSON report and the Markdown one beside it."""
    path = Path(path)
    return path, path.with_suffix(".md")


def write_reports(path: Path, report: dict[str, Any]) -> tuple[Path, Path]:
    """``path`` (JSON) and the same name with ``.md`` (Markdown), written atomically; a partial evaluation's
    report carries ``report["partial"]`` and says so in both."""
    json_path, markdown_path = report_paths(path)
    write_json_atomically(json_path, report)
    text = markdown(report["tables"], report["settings"], report.get("partial"))
    write_bytes_atomically(markdown_path, text.encode())
    return json_path, markdown_path


def check_output_paths(paths: dict[str, Path]) -> None:
    """Refuse, before any rollout, output paths that could not be written after it (``flag -> path``): a folder
    where a file goes, a path under a file, a folder that cannot be written, two outputs on one file."""
    seen: dict[Path, str] = {}
    for flag, path in paths.items():
        resolved = Path(os.path.abspath(path))
        if resolved in seen:
            raise EvaluationError(f"{flag} {path} is also the {seen[resolved]}: give the outputs different names")
        seen[resolved] = flag
        _check_writable(Path(path), flag)


def _check_writable(path: Path, flag: str) -> None:
    if path.is_dir():
        example = {"--output": "results.json", "--rerun": "eval.rrd"}.get(flag)
        fix = f"name a file in it, e.g. {path / example}" if example else "choose another --output"
        raise EvaluationError(f"{flag} {path} is a folder, where a file must go: {fix}")
    if path.exists() and not os.access(path, os.W_OK):
        raise EvaluationError(f"{flag} {path} exists and is read-only: choose another path or make it writable")
    try:
        check_folder_takes_file(path, flag)
    except ValueError as error:
        raise EvaluationError(str(error)) from None

