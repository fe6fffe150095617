"""The smoke preset end to end with the real tools: mosaic-data collect/merge, lerobot-train, mosaic-eval.

The fast suite runs the learning recipe (collect, train, evaluate every checkpoint, report) with a SIGTERM in its
training stage, a resume that reruns that stage only, and a rerun that skips it all. The fine-tune recipe (a
novel-task model, fine-tuned and from-scratch runs: eight stages) runs end to end under ``-m slow``; its commands are
checked in test_plans.py. Both share one data folder, as experiments of one preset may. Every policy type trains and
evaluates through the same commands in tests/policy/test_all_policies.py; the report's tables and figures of every
recipe are checked in test_report.py."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tests.helpers.processes import running_command_lines

from mosaic_data.constants import POLICY_TYPES
from pipelines.experiments.presets import resolve_preset
from pipelines.experiments.recipes import build_plan
from pipelines.experiments.stages import is_done, stage_folder

EXPERIMENT = [sys.executable, "-m", "pipelines.experiments.cli"]
FINE_TUNE_FRACTION = 50


@pytest.fixture(scope="module")
def smoke_data(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("experiment_data")


def _run(arguments: list[str], **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([*EXPERIMENT, *arguments], capture_output=True, text=True, timeout=1200, **kwargs)


def _kill_in_stage_and_resume(arguments: list[str], output: Path, plan, target, lost_machine: bool) -> None:
    """Runs the recipe until ``target`` has started, then stops it: ``lost_machine`` kills the driver and its stage
    at once (no clean-up); otherwise SIGTERM goes to the driver alone, as `kill PID` or a job scheduler sends it, and
    the driver must stop the stage's command before it ends (status 143). Either way exactly the stages before
    ``target`` are done; run again, the recipe skips those untouched and resumes ``target`` alone."""
    driver = subprocess.Popen([*EXPERIMENT, *arguments], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              start_new_session=True)
    deadline = time.monotonic() + 900
    while not (stage_folder(output, target) / "log.txt").exists():
        assert driver.poll() is None, driver.stdout.read().decode()[-3000:]
        assert time.monotonic() < deadline
        time.sleep(0.2)
    time.sleep(2)  # into lerobot-train's start
    if lost_machine:
        os.killpg(driver.pid, signal.SIGKILL)
        driver.wait()
    else:
        driver.send_signal(signal.SIGTERM)
        said = driver.communicate(timeout=120)[0].decode()
        assert driver.returncode == 128 + signal.SIGTERM, said[-3000:]
        assert "interrupted; run the same command again to resume" in said
        left = [line for line in running_command_lines().values() if str(target.output) in line]
        assert left == []  # the stage's lerobot-train ended with the driver
    finished = {s.key: (stage_folder(output, s) / "done.json").stat().st_mtime for s in plan.stages if is_done(output, s)}
    assert set(finished) == {s.key for s in plan.stages[: plan.stages.index(target)]}

    result = _run(arguments)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert result.stdout.count("done before, skipped") == len(finished)
    assert f"{target.title} (resuming) ..." in result.stdout
    assert result.stdout.count("(resuming)") == 1
    for key, mtime in finished.items():
        assert (output / "stages" / key / "done.json").stat().st_mtime == mtime


@pytest.mark.slow
def test_fine_tune_smoke_killed_in_a_stage_resumes_that_stage_only(smoke_data, tmp_path):
    output = tmp_path / "fine"
    overrides = [f"fine_tune_fractions={FINE_TUNE_FRACTION}", "fine_tune_save_every=2"]  # one checkpoint per run
    arguments = ["run", "fine-tune", "--preset", "smoke", "--output", str(output), "--data-dir", str(smoke_data),
                 *(f"--set={o}" for o in overrides)]
    plan = build_plan("fine-tune", resolve_preset("smoke", overrides), output, smoke_data)
    target = next(s for s in plan.stages if s.key == f"train/fine-tune/door/mosaic/fine-tune-{FINE_TUNE_FRACTION}/seed1")
    _kill_in_stage_and_resume(arguments, output, plan, target, lost_machine=True)
    summary = json.loads((output / "results.json").read_text())["recipes"][0]
    curves = {(c["mode"], c["fraction"]): c for c in summary["curves"]}
    assert set(curves) == {("fine-tune", FINE_TUNE_FRACTION), ("scratch", FINE_TUNE_FRACTION)}
    # fine-tuning curves start at step 0 with the novel-task model's own evaluation (Table II, Novel-task)
    assert all(c["steps"] == ([0, 2] if mode == "fine-tune" else [2]) for (mode, _), c in curves.items())
    assert (output / "figures" / "fine_tune_door_mosaic.png").stat().st_size > 0
    markdown = (output / "results.md").read_text()
    assert "Table II, Novel-task" in markdown and "Table II, Fine-tune" in markdown
    assert "| MOSAIC, from scratch, 50% data |" in markdown
    # the fine-tuned runs started from the novel-task model, trained without the held-out task
    fine = stage_folder(output, target) / "command.txt"
    assert "--policy.path=" in fine.read_text() or "--resume=true" in fine.read_text()
    assert "novel-task/door/mosaic/seed1" in (stage_folder(output, target) / "log.txt").read_text()


def test_learning_smoke_killed_in_training_resumes_it_reports_each_checkpoint_and_reruns_as_done(smoke_data, tmp_path):
    output = tmp_path / "learning"
    overrides = ["steps=4"]  # checkpoints at steps 2 and 4, both evaluated
    arguments = ["run", "learning", "--preset", "smoke", "--output", str(output), "--data-dir", str(smoke_data),
                 *(f"--set={o}" for o in overrides)]
    plan = build_plan("learning", resolve_preset("smoke", overrides), output, smoke_data)
    target = next(s for s in plan.stages if s.key.startswith("train/"))
    _kill_in_stage_and_resume(arguments, output, plan, target, lost_machine=False)
    for stage in plan.stages:  # each stage kept its exact command (the dry run's) and its log
        folder = stage_folder(output, stage)
        assert (folder / "command.txt").read_text().strip() == stage.shell_line()
        assert (folder / "log.txt").stat().st_size > 0 and is_done(output, stage)
    recipe = json.loads((output / "results.json").read_text())["recipes"][0]
    points = recipe["curves"][0]["points"]
    assert [p["step"] for p in points] == [2, 4] and all(p["episodes"] == 4 for p in points)
    assert set(points[-1]["per_variation"]) == {"0", "1", "2", "3"}
    # the table's number is the last checkpoint's evaluation's own: read it back from mosaic-eval's results file
    (cell,) = recipe["cells"]
    task_row = next(iter(json.loads(plan.evaluations[-1].results.read_text())["tables"].values()))["per_task"][0]
    assert cell["mean"] == task_row["mean"] == points[-1]["success"] and cell["episodes"] == 4
    markdown = (output / "results.md").read_text()
    interval = f"[{100 * cell['ci95_low']:.1f}, {100 * cell['ci95_high']:.1f}] (n=4)"
    assert f"| {POLICY_TYPES['mosaic']} | {100 * cell['mean']:.1f} +- 0.0 {interval} (paper 67.1) |" in markdown
    assert "Learning curve: every saved checkpoint" in markdown
    assert (output / "figures" / "learning_door_mosaic.png").stat().st_size > 10_000
    assert (output / "figures" / "confusion_learning_mosaic_door.png").stat().st_size > 0
    # a second run finds everything done and only rewrites the report
    again = _run(arguments)
    assert again.returncode == 0 and again.stdout.count("done before, skipped") == len(plan.stages)
