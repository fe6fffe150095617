"""The confusion matrix on the real simulator: the expert of the demonstrated variation lands on the diagonal, an
expert that always does another variation (an agent blind to the demonstration) lands in that variation's column."""

from __future__ import annotations

import json

import pytest

from pipelines.evaluation.agents import AgentSpec
from pipelines.evaluation.confusion import NONE_COLUMN, heat_map_path, write_heat_maps
from pipelines.evaluation.demo_sources import DemoSourceSpec
from pipelines.evaluation.intervals import rate_interval
from pipelines.evaluation.report import print_table, summarize, write_reports
from pipelines.evaluation.rollouts import EpisodeSpec
from pipelines.evaluation.runner import run_episodes
from pipelines.evaluation.seeds import episode_seeds

WRONG = 3  # "pull the right door open": the blind expert does it whatever the episode's variation


@pytest.fixture(scope="module")
def door_results():
    agents = [AgentSpec("expert", "expert"), AgentSpec("expert", "blind expert", expert_variation=WRONG)]
    seeds = {variation: episode_seeds(7, variation) for variation in (0, WRONG)}
    specs = [
        EpisodeSpec(agent, "door", variation, 0, seeds[variation].agent, seeds[variation].demo)
        for agent in range(len(agents)) for variation in (0, WRONG)
    ]
    results = run_episodes(specs, agents, DemoSourceSpec(), workers=1)
    return results, summarize(results, {"expert": {0: "expert"}, "blind": {1: "blind expert"}})


def test_the_expert_fills_the_diagonal_and_a_blind_one_its_own_column(door_results):
    results, tables = door_results
    by_agent = {(r.agent, r.variation): r for r in results}
    assert by_agent["expert", 0].achieved_variation == 0 and by_agent["expert", WRONG].achieved_variation == WRONG
    wrong = by_agent["blind expert", 0]
    assert not wrong.success and wrong.achieved_variation == WRONG and wrong.steps == wrong.horizon
    assert by_agent["blind expert", WRONG].success and by_agent["blind expert", WRONG].achieved_variation == WRONG

    expert = tables["expert"]["per_task"][0]["confusion"]
    assert expert["rows"] == [0, WRONG] and expert["columns"] == [0, 1, 2, 3, NONE_COLUMN]
    assert expert["counts"] == [[1, 0, 0, 0, 0], [0, 0, 0, 1, 0]] and expert["wrong_variation_share"] == 0.0
    blind = tables["blind"]["per_task"][0]["confusion"]
    assert blind["counts"] == [[0, 0, 0, 1, 0], [0, 0, 0, 1, 0]], "row 0 counted in the column of what it did"
    assert blind["wrong_variation_share"] == 0.5
    assert "per_checkpoint" not in blind  # one checkpoint: nothing to break down

    lines = print_table(tables).splitlines()
    assert lines[-1].split() == ["door", "wrong", "variation", "0.0%", "50.0%"]


def test_reports_carry_the_matrix_and_a_heat_map_per_agent(tmp_path, door_results):
    results, tables = door_results
    report = {"settings": {"episodes_per_variation": 1, "seed": 7, "demo_source": "expert"}, "tables": tables,
              "episodes": [r.summary() for r in results]}
    json_path, markdown_path = write_reports(tmp_path / "results.json", report)
    written = json.loads(json_path.read_text())
    assert written["tables"]["blind"]["per_task"][0]["confusion"]["counts"][0] == [0, 0, 0, 1, 0]
    assert [e["achieved_variation"] for e in written["episodes"]] == [0, WRONG, WRONG, WRONG]
    markdown = markdown_path.read_text()
    assert "### door: blind" in markdown and "| demonstrated \\ achieved | 0 | 1 | 2 | 3 | none |" in markdown
    assert "| 0 | **0** | 0 | 0 | 1 | 0 |" in markdown and "| 3 | 0 | 0 | 0 | **1** | 0 |" in markdown
    assert "- 3: pull the right door open, towards the robot" in markdown

    paths = write_heat_maps(tmp_path, tables)
    assert paths == [tmp_path / "confusion_door_expert.png", tmp_path / "confusion_door_blind.png"]
    assert all(path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for path in paths)
    assert heat_map_path(tmp_path, "door", "blind", several_agents=False) == tmp_path / "confusion_door.png"


def test_several_checkpoints_are_summed_and_kept_apart(door_results):
    results, _ = door_results
    tables = summarize(results, {"both": {0: "expert", 1: "blind expert"}})
    matrix = tables["both"]["per_task"][0]["confusion"]
    assert matrix["counts"] == [[1, 0, 0, 1, 0], [0, 0, 0, 2, 0]]
    assert matrix["per_checkpoint"] == {"expert": [[1, 0, 0, 0, 0], [0, 0, 0, 1, 0]],
                                        "blind expert": [[0, 0, 0, 1, 0], [0, 0, 0, 1, 0]]}
    # both checkpoints replay the same 2 instances: 3 successes in 4 episodes is a rate of 0.75 on 2 trials
    row = tables["both"]["per_task"][0]
    assert (row["episodes"], row["successes"], row["instances"], row["mean"]) == (4, 3, 2, 0.75)
    assert (row["ci95_low"], row["ci95_high"]) == pytest.approx(rate_interval(0.75, 2))
    assert "75.0 +- 25.0 [19.8, 97.3] (n=2)" in print_table(tables)  # not 3/4: [30.1, 95.4] (n=4)
