"""Did a change help, on the same episodes? Two ``mosaic-eval`` results compared episode by episode.

    python -m pipelines.evaluation.compare BEFORE/results.json AFTER/results.json [--output compare.json]

Two evaluations run with the same ``--seed``, tasks and episode count replay the same held-out instances with the
same demonstrations, so the question "does option X help this checkpoint?" (an inference option such as
``--policy.temporal_ensemble_coeff``, or averaged weights against trained ones) is answered pair by pair: only the
episodes where exactly one of the two succeeded move the difference. Two separate Wilson intervals overlap long
after the paired difference is clear; this reports, per task, per variation and per checkpoint, both success rates,
``after - before`` with its 95% paired interval (:func:`~pipelines.evaluation.intervals.paired_difference_interval`),
the episodes each one alone succeeded in, and another variation's goal before and after. As in mosaic-eval's
tables, checkpoints that replayed the same instances count each instance once (their outcomes averaged).

Episodes are paired by checkpoint, task, variation and episode index. A checkpoint is the same on both sides when
its path is (one checkpoint rolled out two ways); two results with no checkpoint in common and as many on each side
pair them in order (two trainings, or a policy and ``--baseline expert``, on the same episodes). Paired episodes
must have the same seeds (the same demonstration too, where both agents were shown one): results of different
``--seed`` or episode counts are refused, not compared. ``--output`` writes the rows as JSON and the table as
Markdown beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from mosaic_data.atomic_files import write_bytes_atomically, write_json_atomically
from mosaic_data.cli_args import OneLineErrorParser

from .intervals import paired_difference_interval, rate_interval
from .options import EvaluationError
from .report import check_output_paths, report_paths

EpisodeKey = tuple[str, str, int, int]
"""(checkpoint label, task, variation, episode index): one episode of one checkpoint."""


@dataclass(frozen=True)
class PairedRow:
    """One row of the comparison: a task, one of its variations, or one checkpoint on a task."""

    task: str
    scope: str
    episodes: int
    instances: int
    before: float
    after: float
    difference: float
    difference_low: float
    difference_high: float
    after_only: int
    before_only: int
    before_other_goal: float
    after_other_goal: float


@dataclass
class Pairing:
    """The paired episodes, the checkpoints they belong to (in the first result's order) and what was left out."""

    pairs: list[tuple[dict[str, Any], dict[str, Any]]]
    checkpoints: list[tuple[str, str]]
    notes: list[str]


def load_episodes(path: Path) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The episodes of a results.json and its settings; EvaluationError naming the fix on a bad file."""
    try:
        report = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise EvaluationError(f"{path} does not exist: give the results.json that mosaic-eval --output wrote") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise EvaluationError(
            f"{path} is not a readable JSON file ({error}): give a results.json of mosaic-eval"
        ) from None
    episodes = report.get("episodes") if isinstance(report, dict) else None
    if not isinstance(episodes, list) or not episodes:
        raise EvaluationError(f"{path} holds no episodes: give a results.json that mosaic-eval --output wrote")
    needed = ("agent", "task", "variation", "episode", "seed", "success")
    if not all(isinstance(episode, dict) and all(name in episode for name in needed) for episode in episodes):
        raise EvaluationError(
            f"{path}: an episode lacks one of {', '.join(needed)}: give a results.json of mosaic-eval"
        )
    return episodes, report.get("settings", {})


def _labels(episodes: list[dict[str, Any]]) -> list[str]:
    return list(dict.fromkeys(str(episode["agent"]) for episode in episodes))


def pair_episodes(before: list[dict[str, Any]], after: list[dict[str, Any]]) -> Pairing:
    """Pair the episodes of the checkpoints both results hold (by label: the same checkpoint rolled out two ways);
    with no label in common and as many checkpoints on each side, the first with the first and so on (two trainings
    on the same episodes). EvaluationError unless the paired checkpoints ran the same episodes with the same seeds."""
    before_labels, after_labels = _labels(before), _labels(after)
    shared = [label for label in before_labels if label in after_labels]
    notes = []
    if shared:  # partner: each paired checkpoint's label in the first result -> its label in the second
        partner = {label: label for label in shared}
        left_out = [label for label in before_labels + after_labels if label not in partner]
        if left_out:
            notes.append(f"left out, evaluated on one side only: {', '.join(left_out)}")
    elif len(before_labels) == len(after_labels):
        partner = dict(zip(before_labels, after_labels))
        notes.append("no checkpoint in common: paired by their order in each result")
    else:
        raise EvaluationError(
            f"the two results share no checkpoint and hold {len(before_labels)} and {len(after_labels)}: compare "
            "results of the same checkpoints, or of as many checkpoints in the same order"
        )

    def keyed(episodes: list[dict[str, Any]], names: dict[str, str]) -> dict[EpisodeKey, dict[str, Any]]:
        return {
            (names[str(e["agent"])], str(e["task"]), int(e["variation"]), int(e["episode"])): e
            for e in episodes if str(e["agent"]) in names
        }

    first = keyed(before, {label: label for label in partner})
    second = keyed(after, {label: first_label for first_label, label in partner.items()})
    if first.keys() != second.keys():
        raise EvaluationError(
            f"the paired checkpoints ran different episodes ({len(first.keys() - second.keys())} only in the first "
            f"result, {len(second.keys() - first.keys())} only in the second): evaluate both with the same tasks, "
            "variations and --episodes-per-variation"
        )
    pairs = []
    for key in sorted(first):
        one, other = first[key], second[key]
        demos = [episode.get("demo_seed") for episode in (one, other)]
        if one["seed"] != other["seed"] or (None not in demos and demos[0] != demos[1]):
            raise EvaluationError(
                f"episode {key[3]} of {key[1]} variation {key[2]} ran on seed {one['seed']} (demonstration "
                f"{demos[0]}) in the first result and {other['seed']} ({demos[1]}) in the second: evaluate both "
                "with the same --seed and demonstrations"
            )
        pairs.append((one, other))
    return Pairing(pairs, list(partner.items()), notes)


def _other_goal(episode: dict[str, Any]) -> bool:
    return not episode["success"] and episode.get("achieved_variation") is not None


def paired_row(task: str, scope: str, pairs: list[tuple[dict[str, Any], dict[str, Any]]]) -> PairedRow:
    """The row of ``pairs``: counts averaged over the checkpoints that replayed each instance, so the interval
    counts instances, not episodes."""
    instances = len({(b["task"], b["variation"], b["episode"]) for b, _ in pairs})
    checkpoints = len(pairs) / instances
    both = sum(b["success"] and a["success"] for b, a in pairs)
    after_only = sum(a["success"] and not b["success"] for b, a in pairs)
    before_only = sum(b["success"] and not a["success"] for b, a in pairs)
    neither = len(pairs) - both - after_only - before_only
    low, high = paired_difference_interval(*(count / checkpoints for count in (both, after_only, before_only, neither)))
    before = (both + before_only) / len(pairs)
    after = (both + after_only) / len(pairs)
    return PairedRow(
        task=task, scope=scope, episodes=len(pairs), instances=instances, before=before, after=after,
        difference=after - before, difference_low=low, difference_high=high, after_only=after_only,
        before_only=before_only, before_other_goal=sum(_other_goal(b) for b, _ in pairs) / len(pairs),
        after_other_goal=sum(_other_goal(a) for _, a in pairs) / len(pairs),
    )


def compare(pairing: Pairing) -> list[PairedRow]:
    """Per task: all its episodes, then each variation, then each checkpoint (when there are several)."""
    position = {label: index for index, (label, _) in enumerate(pairing.checkpoints)}
    by_task: dict[str, list] = defaultdict(list)
    for pair in pairing.pairs:
        by_task[pair[0]["task"]].append(pair)
    rows = []
    for task, task_pairs in by_task.items():
        rows.append(paired_row(task, "all", task_pairs))
        by_variation: dict[int, list] = defaultdict(list)
        by_checkpoint: dict[int, list] = defaultdict(list)
        for pair in task_pairs:
            by_variation[pair[0]["variation"]].append(pair)
            by_checkpoint[position[str(pair[0]["agent"])]].append(pair)
        rows += [paired_row(task, f"variation {v}", by_variation[v]) for v in sorted(by_variation)]
        if len(by_checkpoint) > 1:
            rows += [paired_row(task, f"checkpoint {c + 1}", by_checkpoint[c]) for c in sorted(by_checkpoint)]
    return rows


def _percent(rate: float) -> str:
    return f"{100 * rate:.1f}%"


def _rate_text(rate: float, instances: int) -> str:
    low, high = rate_interval(rate, instances)
    return f"{_percent(rate)} [{100 * low:.1f}, {100 * high:.1f}]"


def markdown(rows: list[PairedRow], pairing: Pairing, before_label: str, after_label: str) -> str:
    """The comparison as a Markdown table, with what each side was and which checkpoints were paired."""
    lines = [f"before: {before_label}", f"after: {after_label}"]
    for index, (first, second) in enumerate(pairing.checkpoints):
        lines.append(f"checkpoint {index + 1}: {first}" + ("" if first == second else f" | {second}"))
    lines += pairing.notes
    lines += [
        "",
        "| task | rows | episodes (instances) | before [95%] | after [95%] | after - before, points [95% paired] "
        "| succeeded only after / only before | another variation's goal, before -> after |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        difference = f"{100 * row.difference:+.1f} [{100 * row.difference_low:+.1f}, {100 * row.difference_high:+.1f}]"
        if row.scope == "all":
            difference = f"**{difference}**"
        lines.append(
            f"| {row.task} | {row.scope} | {row.episodes} ({row.instances}) | {_rate_text(row.before, row.instances)} "
            f"| {_rate_text(row.after, row.instances)} | {difference} | {row.after_only} / {row.before_only} "
            f"| {_percent(row.before_other_goal)} -> {_percent(row.after_other_goal)} |"
        )
    return "\n".join(lines) + "\n"


def side_label(path: Path, settings: dict[str, Any]) -> str:
    """The file and how its checkpoints acted (the inference options mosaic-eval was given), e.g.
    ``a/results.json (temporal_ensemble_coeff=0.1)``."""
    options = sorted(
        {f"{name}={value}" for agent in settings.get("agents", []) for name, value in agent.get("policy_options", [])}
    )
    return f"{path} ({', '.join(options) if options else 'as the checkpoints\' configs say'})"


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="python -m pipelines.evaluation.compare", description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path, metavar="BEFORE", help="results.json of mosaic-eval: the reference")
    parser.add_argument("after", type=Path, metavar="AFTER", help="results.json of the same episodes: the change")
    parser.add_argument(
        "--output", type=Path, metavar="COMPARE.json", help="write the rows (JSON) and the table (.md beside it)"
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.output is not None:
            check_output_paths({"--output": args.output})
        before, before_settings = load_episodes(args.before)
        after, after_settings = load_episodes(args.after)
        pairing = pair_episodes(before, after)
    except EvaluationError as error:
        print(f"compare: {error}", file=sys.stderr)
        return 2
    rows = compare(pairing)
    text = markdown(rows, pairing, side_label(args.before, before_settings), side_label(args.after, after_settings))
    print(text, end="")
    if args.output is not None:
        json_path, markdown_path = report_paths(args.output)
        write_json_atomically(
            json_path,
            {
                "before": str(args.before),
                "after": str(args.after),
                "checkpoints": [list(pair) for pair in pairing.checkpoints],
                "notes": pairing.notes,
                "rows": [asdict(row) for row in rows],
            },
        )
        write_bytes_atomically(markdown_path, text.encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
