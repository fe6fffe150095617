"""The rollout trace replays mosaic-eval's own episode beside the expert on the same instance (real simulator)."""

from __future__ import annotations

import csv
import json

import numpy as np

from pipelines.bench.rollout_trace import build_parser, main, trace_episodes
from pipelines.evaluation.cli import main as mosaic_eval

STEPS = 6


def test_trace_replays_the_evaluated_episode_beside_the_expert(tmp_path, tiny_checkpoint, capsys):
    results = tmp_path / "results.json"
    code = mosaic_eval([
        f"--policy.path={tiny_checkpoint}", "--task", "door", "--variations", "1", "--episodes-per-variation", "2",
        "--workers", "1", "--max-steps", str(STEPS), "--output", str(results), "--quiet",
    ])
    assert code == 0
    evaluated = {e["episode"]: e for e in json.loads(results.read_text())["episodes"]}
    args = build_parser().parse_args([
        f"--policy.path={tiny_checkpoint}", "--task", "door", "--variation", "1", "--episodes", "1",
        "--max-steps", str(STEPS),
    ])
    ((episode, result, policy, expert),) = trace_episodes(args)
    assert episode == 1 and len(policy) == len(expert) == STEPS
    row = evaluated[1]
    assert (result.seed, result.demo_seed, result.success) == (row["seed"], row["demo_seed"], row["success"])
    assert result.final_position == row["final_position"], "the trace must replay mosaic-eval's episode"
    assert np.allclose(policy.hands[0], expert.hands[0]), "both agents start on the same instance"
    assert expert.phases[0] == "approach" and policy.phases == [None] * STEPS
    assert not np.allclose(policy.targets, expert.targets)  # an untrained policy acts unlike the expert

    output = tmp_path / "trace.csv"
    assert main([*_argv(tiny_checkpoint), "--episodes", "1", "--output", str(output), "--every", "2"]) == 0
    printed = capsys.readouterr().out
    assert "door, variation 1 (pull the left door" in printed and "expert: failure in 6 steps" in printed
    assert len([line for line in printed.splitlines() if line.lstrip().startswith(("0 |", "2 |", "4 |"))]) == 3
    rows = list(csv.DictReader(output.open()))
    assert [r["agent"] for r in rows] == ["policy"] * STEPS + ["expert"] * STEPS
    assert rows[STEPS]["phase"] == "approach" and rows[0]["phase"] == ""
    assert np.allclose([float(rows[0][f"hand_{axis}"]) for axis in "xyz"], policy.hands[0], atol=1e-5)


def _argv(checkpoint) -> list[str]:
    return [f"--policy.path={checkpoint}", "--task", "door", "--variation", "1", "--max-steps", str(STEPS)]


def test_bad_task_or_variation_is_one_line(tiny_checkpoint, capsys):
    assert main(["--policy.path", str(tiny_checkpoint), "--task", "doors", "--variation", "0"]) == 2
    assert main(["--policy.path", str(tiny_checkpoint), "--task", "door", "--variation", "9"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 2 and all(line.startswith("rollout_trace: ") for line in errors)
    assert "door" in errors[0] and "--variation" in errors[1]
