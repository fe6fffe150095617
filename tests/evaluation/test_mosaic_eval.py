"""mosaic-eval end to end on the real simulator: a tiny untrained checkpoint, the expert row, reports, rerun."""

from __future__ import annotations

import json

import numpy as np
import pytest
from tests.helpers.recordings import rows_per_entity

from pipelines.evaluation.cli import main as mosaic_eval
from pipelines.evaluation.intervals import interval_text, wilson_interval
from pipelines.evaluation.report import TERMINAL_LEGEND


def _run(tmp_path, *args):
    output = tmp_path / "results.json"
    code = mosaic_eval([*args, "--output", str(output), "--quiet"])
    return code, output


def test_untrained_checkpoint_one_episode_reports_and_recording(tmp_path, tiny_checkpoint):
    recording = tmp_path / "eval.rrd"
    code, output = _run(
        tmp_path, f"--policy.path={tiny_checkpoint}", "--task", "door", "--variations", "1",
        "--episodes-per-variation", "1", "--workers", "1", "--max-steps", "12", "--rerun", str(recording),
    )
    assert code == 0
    report = json.loads(output.read_text())
    assert set(report) == {"settings", "tables", "timing", "episodes"}
    table = report["tables"]["mosaic"]
    (row,) = table["per_variation"]
    assert row["task"] == "door" and row["variation"] == 1 and row["description"].startswith("pull the left door")
    assert {"episodes", "successes", "mean", "std_episodes", "std_checkpoints", "per_checkpoint"} <= set(row)
    assert row["episodes"] == 1 and table["per_task"][0]["task"] == "door" and table["overall"]["episodes"] == 1
    (episode,) = report["episodes"]
    assert episode["steps"] == 12 and episode["success"] is False  # untrained: no luck in 12 steps
    assert episode["seed"] != episode["demo_seed"], "the demonstration must show another instance"
    assert report["timing"]["steps"] == 12 and report["timing"]["act_ms_per_step"] > 0
    markdown = output.with_suffix(".md").read_text()
    assert "| door |" in markdown and "door 1: pull the left door open" in markdown

    rows = rows_per_entity(recording)
    assert rows["/agent/camera"] == rows["/action/x"] == rows["/agent/camera/attention"] == 12
    assert rows["/demo/video"] > 12, "the whole demonstration is in the recording"
    assert {"/demo/used/0", "/demo/used/3/attention", "/attention_on_demo/layer_1", "/success", "/episode"} <= set(rows)


def test_expert_row_reaches_its_target_on_door_with_two_workers(tmp_path, capsys):
    code, output = _run(tmp_path, "--baseline", "expert", "--task", "door", "--episodes-per-variation", "2", "--workers", "2")
    assert code == 0
    report = json.loads(output.read_text())
    overall = report["tables"]["expert"]["overall"]
    assert overall["episodes"] == 8 and overall["mean"] >= 0.95
    confusion = report["tables"]["expert"]["per_task"][0]["confusion"]
    assert sum(confusion["counts"][v][v] for v in range(4)) == round(8 * overall["mean"])  # successes: the diagonal
    assert report["timing"]["workers"] == 2
    # every cell: its episodes, successes and 95% Wilson interval, in the JSON, the Markdown and the terminal
    task_row = report["tables"]["expert"]["per_task"][0]
    assert (task_row["episodes"], task_row["instances"], task_row["successes"]) == (8, 8, round(8 * task_row["mean"]))
    assert (task_row["ci95_low"], task_row["ci95_high"]) == pytest.approx(wilson_interval(task_row["successes"], 8))
    assert task_row["ci95_high"] - task_row["ci95_low"] > 0.3, "8 episodes cannot pin a rate down to 30 points"
    text = interval_text((task_row["ci95_low"], task_row["ci95_high"]), 8)
    assert text.endswith("(n=8)")
    cell = f"{100 * task_row['mean']:.1f} +- {100 * task_row['std_episodes']:.1f} {text}"
    markdown = output.with_suffix(".md").read_text()
    assert f"| door | {cell} |" in markdown
    assert "95% Wilson score interval" in markdown
    for row in report["tables"]["expert"]["per_variation"]:
        assert row["episodes"] == row["instances"] == 2 and row["ci95_low"] <= row["mean"] <= row["ci95_high"]
        assert f"| door {row['variation']}: {row['description']} | {100 * row['mean']:.1f} +- " in markdown
        assert f"{interval_text((row['ci95_low'], row['ci95_high']), 2)} |" in markdown
    printed = capsys.readouterr().out.splitlines()
    assert TERMINAL_LEGEND in printed
    (all_line,) = [line for line in printed if line.startswith("door (all)")]
    assert all_line.split(None, 2)[2].strip() == cell


def test_results_do_not_depend_on_the_worker_count(tmp_path, tiny_checkpoint):
    common = [f"--policy.path={tiny_checkpoint}", "--task", "door", "--variations", "0,3", "--episodes-per-variation", "1",
              "--max-steps", "8", "--seed", "5"]
    outcomes = []
    for workers in ("1", "2"):
        code, output = _run(tmp_path / workers, *common, "--workers", workers)
        assert code == 0
        episodes = json.loads(output.read_text())["episodes"]
        outcomes.append([(e["variation"], e["seed"], e["demo_seed"], e["success"], e["final_position"]) for e in episodes])
    assert outcomes[0] == outcomes[1]
    finals = np.array([o[-1] for o in outcomes[0]])
    assert np.all(np.isfinite(finals))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--baseline", "expert", "--task", "laundry"], "unknown task 'laundry'"),
        (["--baseline", "expert", "--task", "doorr"], "unknown task 'doorr' (--task): did you mean 'door'?"),
        (["--baseline", "expert", "--task", "door", "--variations", "4"], "door has variations 0..3"),
        (["--policy.path=/nonexistent/checkpoint", "--task", "door"], "does not exist"),
        (["--task", "door"], "nothing to evaluate"),
        (["--baseline", "expert", "--task", "door", "--episodes-per-variation", "0"], "--episodes-per-variation"),
        (["--baseline", "expert", "--task", "all", "--variations", "0"], "applies to one task"),
    ],
)
def test_bad_input_is_one_line(tmp_path, capsys, args, message):
    code, output = _run(tmp_path, *args)
    error = capsys.readouterr().err.strip()
    assert code == 2 and error.startswith("mosaic-eval: error:") and message in error and "\n" not in error
    assert not output.exists()


def _edited_checkpoint(folder, source, **changes):
    """A copy of ``source``'s config.json with ``changes`` (weights left empty: the plan refuses before loading)."""
    folder.mkdir()
    config = json.loads((source / "config.json").read_text()) | changes
    (folder / "config.json").write_text(json.dumps(config))
    (folder / "model.safetensors").write_bytes(b"")
    return folder


def test_an_act_checkpoint_runs_without_a_demonstration(tmp_path, tiny_act_checkpoint):
    code, output = _run(
        tmp_path, f"--policy.path={tiny_act_checkpoint}", "--task", "door", "--variations", "0,2",
        "--episodes-per-variation", "1", "--workers", "1", "--max-steps", "7",
    )
    assert code == 0
    report = json.loads(output.read_text())
    assert list(report["tables"]) == ["act"]  # checkpoints form one row per policy type
    (agent,) = report["settings"]["agents"]
    assert agent["takes_demo"] is False
    episodes = report["episodes"]
    assert [e["steps"] for e in episodes] == [7, 7], "select_action refills its 5-action chunk on its own"
    assert all(e["demo_seed"] is None for e in episodes), "no demonstration is made for a policy that cannot use it"
    confusion = report["tables"]["act"]["per_task"][0]["confusion"]
    assert confusion["rows"] == [0, 2] and confusion["columns"][-1] == "none"
    assert [sum(row) for row in confusion["counts"]] == [1, 1]
    assert (output.parent / "confusion_door.png").is_file()


def test_mosaic_and_act_are_two_rows_with_a_heat_map_each(tmp_path, capsys, tiny_checkpoint, tiny_act_checkpoint):
    code, output = _run(
        tmp_path, f"--policy.path={tiny_checkpoint}", f"--policy.path={tiny_act_checkpoint}", "--task", "door",
        "--variations", "1", "--episodes-per-variation", "1", "--workers", "1", "--max-steps", "3",
    )
    assert code == 0
    assert list(json.loads(output.read_text())["tables"]) == ["mosaic", "act"]
    assert {p.name for p in output.parent.glob("*.png")} == {"confusion_door_mosaic.png", "confusion_door_act.png"}
    printed = capsys.readouterr().out.splitlines()
    assert [line.split() for line in printed if "wrong variation" in line] == [["door", "wrong", "variation", "0.0%", "0.0%"]]


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"type": "no_such_policy"}, "holds a 'no_such_policy' policy that LeRobot does not know: install"),
        ({"input_features": {"observation.images.wrist": {"type": "VISUAL", "shape": [3, 48, 88]}}},
         "expects input observation.images.wrist but the MOSAIC tasks provide only observation.images.agentview"),
        ({"input_features": {"observation.images.agentview": {"type": "VISUAL", "shape": [3, 48, 88]},
                             "observation.state": {"type": "STATE", "shape": [14]}}},
         "expects observation.state of shape (14,) but the MOSAIC tasks give (10,)"),
        ({"output_features": {"action": {"type": "ACTION", "shape": [14]}}}, "outputs action of shape (14,)"),
    ],
)
def test_a_checkpoint_that_does_not_fit_is_one_line(tmp_path, capsys, tiny_act_checkpoint, changes, message):
    other = _edited_checkpoint(tmp_path / "other", tiny_act_checkpoint, **changes)
    code, _ = _run(tmp_path, f"--policy.path={other}", "--task", "door")
    error = capsys.readouterr().err.strip()
    assert code == 2 and message in error and "\n" not in error


def test_a_folder_without_a_config_is_refused(tmp_path, capsys):
    empty = tmp_path / "not_a_checkpoint"
    empty.mkdir()
    code, _ = _run(tmp_path, f"--policy.path={empty}", "--task", "door")
    assert code == 2 and "no config.json" in capsys.readouterr().err


def test_a_lerobot_train_run_folder_resolves_to_its_last_checkpoint(tmp_path, tiny_checkpoint):
    from pipelines.evaluation.agents import resolve_checkpoint

    run = tmp_path / "run"
    last = run / "checkpoints" / "last"
    last.mkdir(parents=True)
    (last / "pretrained_model").symlink_to(tiny_checkpoint)
    assert resolve_checkpoint(run) == last / "pretrained_model"


def test_demonstrations_from_a_dataset(tmp_path, capsys, tiny_checkpoint):
    from tests.helpers.evaluation import write_demo_dataset

    root = write_demo_dataset(tmp_path / "door_sawyer", "door", [1])
    common = [f"--policy.path={tiny_checkpoint}", "--task", "door", "--episodes-per-variation", "2", "--max-steps", "3",
              "--workers", "1", "--demo-dataset", str(root)]
    code, output = _run(tmp_path, *common, "--variations", "1")
    assert code == 0
    report = json.loads(output.read_text())
    assert report["settings"]["demo_source"] == str(root)
    assert [e["steps"] for e in report["episodes"]] == [3, 3]

    code, _ = _run(tmp_path, *common, "--variations", "0,1")
    error = capsys.readouterr().err
    assert code == 2 and "has no episode of door variation 0" in error and "mosaic-data collect --task door" in error

    small = write_demo_dataset(tmp_path / "small", "door", [1], height=32, width=56)
    code, _ = _run(tmp_path, *common[:-1], str(small), "--variations", "1")
    assert code == 2 and "collect the demonstrations at the policy's image size" in capsys.readouterr().err


def test_policy_options_roll_out_the_checkpoint_another_way(tmp_path, tiny_checkpoint):
    from pipelines.evaluation.agents import AgentSpec, PolicyAgent

    code, output = _run(
        tmp_path, f"--policy.path={tiny_checkpoint}", "--policy.n_action_steps=2", "--task", "door", "--variations", "1",
        "--episodes-per-variation", "1", "--workers", "1", "--max-steps", "5",
    )
    assert code == 0
    (agent,) = json.loads(output.read_text())["settings"]["agents"]
    assert agent["policy_options"] == [["n_action_steps", 2]]  # what was rolled out is on record
    spec = AgentSpec("policy", "mosaic", str(tiny_checkpoint), policy_options=(("n_action_steps", 2),))
    policy = PolicyAgent.from_spec(spec).policy
    assert policy.config.n_action_steps == 2 and policy.config.action_chunk > 2


@pytest.mark.parametrize(
    "option, act, message",
    [
        ("--policy.n_action_steps=99", False, "`n_action_steps` must be between 1 and `action_chunk`"),
        ("--policy.action_sampling=best", False, "`action_sampling` must be one of"),
        ("--policy.action_sampling=sample", True, "--policy.action_sampling is not an option of 'act' policies"),
        ("--policy.temporal_ensemble_coeff=0.01", True, "`n_action_steps` must be 1 when using temporal ensembling"),
        ("--policy.act_with_weight_average=maybe", False, "expected true or false, got 'maybe'"),
    ],
)
def test_a_bad_policy_option_is_one_line(tmp_path, capsys, tiny_checkpoint, tiny_act_checkpoint, option, act, message):
    checkpoint = tiny_act_checkpoint if act else tiny_checkpoint
    code, output = _run(tmp_path, f"--policy.path={checkpoint}", option, "--task", "door")
    error = capsys.readouterr().err.strip()
    assert code == 2 and message in error and "\n" not in error
    assert not output.exists()


def test_a_policy_option_without_a_checkpoint_is_refused(tmp_path, capsys):
    code, _ = _run(tmp_path, "--baseline", "expert", "--policy.n_action_steps=2", "--task", "door")
    assert code == 2 and "pass --policy.path=<checkpoint> with it" in capsys.readouterr().err
