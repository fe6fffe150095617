"""Two mosaic-eval results compared episode by episode: real evaluations on the simulator, paired by checkpoint
and seed, with the paired interval; results of other episodes are refused in one line."""

from __future__ import annotations

import json

import pytest

from pipelines.evaluation.cli import main as mosaic_eval
from pipelines.evaluation.compare import main as compare
from pipelines.evaluation.intervals import paired_difference_interval

EPISODE_ARGS = ["--task", "door", "--variations", "1", "--episodes-per-variation", "2", "--workers", "1", "--quiet"]


@pytest.fixture(scope="module")
def evaluations(tmp_path_factory, tiny_checkpoint):
    """The untrained checkpoint cut at 6 steps, rolled out as its config says and with temporal ensembling, and
    the Panda's expert on the same two episodes."""
    folder = tmp_path_factory.mktemp("compare")
    runs = {
        "chunks": [f"--policy.path={tiny_checkpoint}", "--max-steps", "6"],
        "ensembled": [f"--policy.path={tiny_checkpoint}", "--max-steps", "6", "--policy.temporal_ensemble_coeff=0.01"],
        "expert": ["--baseline", "expert"],
    }
    for name, args in runs.items():
        assert mosaic_eval([*args, *EPISODE_ARGS, "--output", str(folder / name / "results.json")]) == 0
    return folder


def test_the_same_checkpoint_two_ways_is_paired_by_label(evaluations, tiny_checkpoint, tmp_path, capsys):
    output = tmp_path / "compare.json"
    assert compare([str(evaluations / "chunks/results.json"), str(evaluations / "ensembled/results.json"),
                    "--output", str(output)]) == 0
    printed = capsys.readouterr().out
    assert "(temporal_ensemble_coeff=0.01)" in printed and f"checkpoint 1: {tiny_checkpoint}" in printed
    report = json.loads(output.read_text())
    (task_row, variation_row) = report["rows"]
    assert (task_row["scope"], variation_row["scope"]) == ("all", "variation 1")
    assert task_row["episodes"] == task_row["instances"] == 2 and report["notes"] == []
    assert task_row["before"] == task_row["after"] == 0.0  # 6 steps open no door
    assert task_row["difference_low"] < 0 < task_row["difference_high"]
    assert output.with_suffix(".md").read_text() == printed


def test_a_policy_against_the_expert_on_the_same_episodes(evaluations, capsys):
    assert compare([str(evaluations / "chunks/results.json"), str(evaluations / "expert/results.json")]) == 0
    printed = capsys.readouterr().out
    assert "paired by their order" in printed
    row = next(line for line in printed.splitlines() if "| all |" in line)
    expert = json.loads((evaluations / "expert/results.json").read_text())["episodes"]
    gained = sum(e["success"] for e in expert)
    assert gained == 2, "the Panda's expert opens the door"
    low, high = paired_difference_interval(0, gained, 0, 2 - gained)
    assert f"**+100.0 [{100 * low:+.1f}, {100 * high:+.1f}]**" in row and "| 2 / 0 |" in row


def test_results_of_other_episodes_are_refused_in_one_line(evaluations, tmp_path, capsys):
    chunks = evaluations / "chunks/results.json"
    report = json.loads(chunks.read_text())
    report["episodes"][0]["seed"] += 1
    (tmp_path / "seed.json").write_text(json.dumps(report))
    report["episodes"] = report["episodes"][:1]
    (tmp_path / "fewer.json").write_text(json.dumps(report))
    (tmp_path / "broken.json").write_text("{")
    cases = {
        "seed.json": "the same --seed",
        "fewer.json": "--episodes-per-variation",
        "broken.json": "not a readable JSON file",
        "missing.json": "does not exist",
    }
    for name, message in cases.items():
        assert compare([str(chunks), str(tmp_path / name)]) == 2
        error = capsys.readouterr().err
        assert error.startswith("compare: ") and message in error and error.count("\n") == 1, error
