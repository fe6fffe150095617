"""The experiment report reads mosaic-eval results files and puts the right numbers in the right cells."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipelines.evaluation.intervals import wilson_interval
from pipelines.evaluation.report import summarize
from pipelines.evaluation.rollouts import EpisodeResult
from pipelines.experiments import cli
from pipelines.experiments.paper_results import paper_number
from pipelines.experiments.presets import resolve_preset
from pipelines.experiments.recipes import build_plan
from mosaic_data.atomic_files import write_json_atomically


def _results_file(path, task, successes_per_variation, achieved=None):
    """A results.json written by mosaic-eval's own summarizer, from episodes with the given outcomes."""
    results = []
    for variation, outcomes in enumerate(successes_per_variation):
        for episode, success in enumerate(outcomes):
            done = variation if success else (achieved if achieved is not None else None)
            results.append(EpisodeResult(0, "ckpt", task, variation, f"{task} {variation}", episode, episode, None,
                                         bool(success), done, 10, 10, [0.0, 0.0, 0.0], 1.0, 0.5, 0.1))
    tables = summarize(results, {"ckpt": {0: "ckpt"}})
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomically(path, {"tables": tables, "settings": {}})


def test_report_cells_are_the_mean_and_std_over_seeds_of_the_last_checkpoints(tmp_path):
    overrides = ["seeds=2", "eval_checkpoints=2", "methods=mosaic,tosil", "steps=4", "save_every=1"]
    output = tmp_path / "exp"
    args = cli.parse_args(["run", "single-task", "--preset", "smoke", "--output", str(output)])
    cli._record_settings(output, args, overrides, None)
    plan = build_plan("single-task", resolve_preset("smoke", overrides), output)
    final = [e for e in plan.evaluations if e.final]
    assert {e.step for e in final} == {3, 4} and len(final) == 2 * 2 * 2  # methods x seeds x checkpoints
    # door has 4 variations; each results file: 1 episode per variation, `wins` of them successful
    wins = {("mosaic", 1, 3): 1, ("mosaic", 1, 4): 3, ("mosaic", 2, 3): 2, ("mosaic", 2, 4): 2,
            ("tosil", 1, 3): 0, ("tosil", 1, 4): 0}  # tosil seed 2 not evaluated yet
    for evaluation in final:
        key = (evaluation.row, evaluation.seed, evaluation.step)
        if key in wins:
            _results_file(evaluation.results, "door", [[v < wins[key]] for v in range(4)], achieved=3)
    paths = cli.report(output)
    summary = json.loads(paths["json"].read_text())
    cells = {c["row"]: c for c in summary["recipes"][0]["cells"]}
    # mosaic: seed 1 = mean(25%, 75%) = 50%, seed 2 = mean(50%, 50%) = 50%
    assert cells["mosaic"]["success_per_seed"] == {"1": 0.5, "2": 0.5}
    assert cells["mosaic"]["mean"] == 0.5 and cells["mosaic"]["std_over_seeds"] == 0.0
    assert cells["mosaic"]["paper"] == 67.1 and cells["mosaic"]["missing_evaluations"] == 0
    assert cells["tosil"]["success_per_seed"] == {"1": 0.0} and cells["tosil"]["missing_evaluations"] == 2
    assert cells["tosil"]["paper"] == 57.9  # Table I, single-task door
    # failures that did variation 3 (and were not variation 3's own episode) count as the wrong variation
    counts = np.array(cells["mosaic"]["confusion"]["counts"])
    assert counts.sum() == 16 and cells["mosaic"]["episodes"] == 16
    wrong = sum(counts[row, 3] for row in range(3))
    assert cells["mosaic"]["wrong_variation_share"] == wrong / 16
    # the interval: every seed and checkpoint replayed the same 4 instances, so 8 of 16 episodes is 0.5 on 4 trials
    mosaic = cells["mosaic"]
    assert (mosaic["successes"], mosaic["instances"]) == (8, 4)
    assert (mosaic["ci95_low"], mosaic["ci95_high"]) == pytest.approx(wilson_interval(2, 4))
    assert (cells["tosil"]["ci95_low"], cells["tosil"]["ci95_high"]) == pytest.approx(wilson_interval(0, 4))
    markdown = paths["markdown"].read_text()
    assert "| MOSAIC | 50.0 +- 0.0 [15.0, 85.0] (n=4) (paper 67.1) |" in markdown
    assert "| T-OSIL | 0.0 +- 0.0 [0.0, 49.0] (n=4) (2 evaluations to go) (paper 57.9) |" in markdown
    assert "| single-task | mosaic | door | 16 | 50.0% [15.0, 85.0] (n=4) |" in markdown
    assert "95% Wilson interval" in markdown
    assert (output / "figures" / "bars_single-task.png").stat().st_size > 0
    assert (output / "figures" / "confusion_single-task_mosaic_door.png").stat().st_size > 0


def test_a_partial_evaluation_counts_as_missing(tmp_path):
    """mosaic-eval writes the finished episodes of an evaluation that stopped early, marked partial: the stage
    has not finished, so the report must not take those episodes for the cell's result."""
    output = tmp_path / "exp"
    args = cli.parse_args(["run", "single-task", "--preset", "smoke", "--output", str(output)])
    cli._record_settings(output, args, ["methods=mosaic"], None)
    plan = build_plan("single-task", resolve_preset("smoke", ["methods=mosaic"]), output)
    evaluation = plan.evaluations[0]
    _results_file(evaluation.results, "door", [[True], [True], [True]])
    content = json.loads(evaluation.results.read_text())
    write_json_atomically(evaluation.results, {**content, "partial": {"finished": 3, "planned": 4, "reason": "died"}})
    cell = json.loads(cli.report(output)["json"].read_text())["recipes"][0]["cells"][0]
    assert cell["mean"] is None and cell["missing_evaluations"] == 1
    assert cell["ci95_low"] is None and cell["ci95_high"] is None and cell["instances"] == 0


def test_the_learning_report_has_a_curve_point_per_checkpoint_and_each_variations_success(tmp_path):
    overrides = ["steps=4", "save_every=2"]
    output = tmp_path / "exp"
    args = cli.parse_args(["run", "learning", "--preset", "smoke", "--output", str(output)])
    cli._record_settings(output, args, overrides, None)
    plan = build_plan("learning", resolve_preset("smoke", overrides), output)
    assert [e.step for e in plan.evaluations] == [2, 4]
    # step 2: variation 0 succeeds; step 4: variations 0, 1 and 2 succeed, and variation 3's episode did variation 0
    _results_file(plan.evaluations[0].results, "door", [[True], [False], [False], [False]])
    _results_file(plan.evaluations[1].results, "door", [[True], [True], [True], [False]], achieved=0)
    paths = cli.report(output)
    recipe = json.loads(paths["json"].read_text())["recipes"][0]
    points = recipe["curves"][0]["points"]
    assert [(p["step"], p["success"]) for p in points] == [(2, 0.25), (4, 0.75)]
    assert points[1]["per_variation"] == {"0": 1.0, "1": 1.0, "2": 1.0, "3": 0.0}
    assert points[1]["wrong_variation_share"] == 0.25 and points[1]["ci95"] == pytest.approx(wilson_interval(3, 4))
    assert [c["mean"] for c in recipe["cells"]] == [0.75]  # the table's cell: the last checkpoint
    markdown = paths["markdown"].read_text()
    assert "| 4 | 75.0 [30.1, 95.4] (n=4) | 25.0 | 100 | 100 | 100 | 0 |" in markdown
    assert "(paper 67.1)" in markdown  # MOSAIC's single-task door number
    assert (output / "figures" / "learning_door_mosaic.png").stat().st_size > 10_000


@pytest.mark.parametrize("row, task, expected", [
    ("paper", "door", 67.1),  # the reference row is Table I's single-task MOSAIC
    ("contrastive_off", "door", 62.5),  # appendix, "Single-task w/o Contra."
    ("positive_same", "pick_place", 12.3),  # appendix, No-Temp
    ("positive_fixed", "basketball", 52.5),  # appendix, Fix-Temp
    ("contrastive_before", "nut_assembly", 17.8),  # appendix, Pre-Attn
    ("contrastive_after", "pick_place", 51.5),  # appendix, Post-Attn
    ("positive_fixed", "door", None),  # measured on three tasks only
    ("chunk_10", "door", None),  # this project's own row
])
def test_ablation_cells_carry_the_appendix_numbers_and_none_where_the_paper_has_none(row, task, expected):
    assert paper_number("ablations", row, task) == expected
