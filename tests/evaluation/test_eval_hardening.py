"""mosaic-eval under failure: dead workers, bad output paths, bad numbers, incomplete checkpoints, damaged demo
videos, unknown demo datasets. Every case must end in one line that names the fix, before any rollout where the
input is at fault, and never lose episodes that finished."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from tests.helpers.cli_errors import one_line_error
from tests.helpers.processes import alive, kill_tree
from tests.helpers.video_damage import drop_last_frames, overwrite_middle

from pipelines.evaluation.cli import main as mosaic_eval

REPO = Path(__file__).resolve().parents[2]
SMALL = ["--task", "door", "--variations", "0", "--episodes-per-variation", "1", "--max-steps", "5", "--workers", "1"]


def _run(tmp_path: Path, *args: str, output: Path | None = None) -> tuple[int, Path]:
    output = output or tmp_path / "results.json"
    return mosaic_eval([*args, "--output", str(output), "--quiet"]), output


def _one_line_error(capsys) -> str:
    return one_line_error(capsys, command="mosaic-eval")


# ---------------------------------------------------------------------------------------------- 1. dead workers


PLANNED = 2000
"""Episodes of the killed-worker evaluation: the kill comes after the first one, so the plan only has to outlast the
killer's reaction. 2000 last about 7 minutes; the kill ends them in seconds, and the killer's deadline ends them if
no episode finishes."""


def test_a_killed_worker_stops_the_evaluation_and_keeps_the_finished_episodes(tmp_path):
    output, log, report_path = tmp_path / "results.json", tmp_path / "stderr.log", tmp_path / "killer.json"
    command = [
        sys.executable, "-m", "pipelines.evaluation.cli", "--baseline", "expert", "--task", "door", "--variations", "0",
        "--episodes-per-variation", str(PLANNED), "--max-steps", "100", "--workers", "2", "--output", str(output),
    ]
    with log.open("wb") as stderr_file:  # a file the killer polls: no reader thread between the command and the test
        process = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=stderr_file)
    killer = [sys.executable, "-m", "tests.helpers.worker_killer", str(process.pid), str(log), str(PLANNED), str(report_path)]
    try:
        subprocess.run(killer, cwd=REPO, check=True, timeout=600)
        code = process.wait(timeout=120)  # the lost episode must not keep the command waiting
    finally:
        if process.poll() is None:
            kill_tree(process.pid)
            process.wait()
    report = json.loads(report_path.read_text())
    lines = log.read_bytes().decode(errors="replace").replace("\r", "\n").strip().splitlines()
    # A failure here shows what the killer saw and the command's last lines (a run in the full suite once exited 0
    # after the kill and could not be told apart without them).
    assert "error" not in report, report
    assert code == 1 and report["victim_died"] and report["stopped_after_kill_s"] is not None, (code, report, lines[:4], lines[-3:])
    assert report["stopped_after_kill_s"] < 60, report
    assert "Traceback" not in "\n".join(lines)
    last = lines[-1]
    assert last.startswith("mosaic-eval: error: evaluation worker mosaic-eval-") and "died (killed by SIGKILL" in last
    assert "out-of-memory" in last and "partial results" in last and str(output) in last
    results = json.loads(output.read_text())
    partial, episodes = results["partial"], results["episodes"]
    assert partial["planned"] == PLANNED and 1 <= partial["finished"] == len(episodes) < PLANNED
    assert partial["reason"].startswith("evaluation worker")
    assert results["tables"]["expert"]["overall"]["episodes"] == len(episodes)
    assert "Partial results" in output.with_suffix(".md").read_text()
    assert not any(alive(pid) for pid in report["workers"]), "the other worker must be stopped too"


def test_a_partial_report_with_an_agent_that_finished_nothing_still_renders(tmp_path):
    """Agents of a stopped evaluation cover different episodes: the tables go by task and variation, not row index."""
    from pipelines.evaluation.report import markdown, print_table, summarize
    from pipelines.evaluation.rollouts import EpisodeResult

    def result(variation: int, success: bool) -> EpisodeResult:
        return EpisodeResult(0, "expert", "door", variation, f"door {variation}", 0, 1, 2, success, variation if success else None,
                             5, 5, [0.0, 0.0, 0.0], 0.1, 0.01, 0.0)

    tables = summarize([result(0, True), result(2, False)], {"expert": {0: "expert"}, "untrained": {1: "untrained"}})
    settings = {"episodes_per_variation": 1, "seed": 0, "demo_source": "fresh"}
    assert "| door 2: door 2 | 0.0 +- 0.0 [0.0, 79.3] (n=1) | - |" in markdown(tables, settings)
    assert "door wrong variation  0.0%" in print_table(tables)
    assert "Partial results: 2 of 8" in markdown(tables, settings, {"finished": 2, "planned": 8, "reason": "a worker died"})


# ---------------------------------------------------------------------------------------------- 2. output paths


def _unwritable_folder(tmp_path: Path) -> Path:
    """A folder this process cannot create files in (root passes permission bits: then a kernel folder)."""
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        tempfile.NamedTemporaryFile(dir=folder).close()
    except OSError:
        return folder
    return Path("/sys")


@pytest.mark.parametrize("case", ["a folder", "under a file", "unwritable", "markdown is a folder", "rerun under a file", "md"])
def test_output_paths_are_checked_before_any_work(tmp_path, capsys, case):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    output, extra, flag = tmp_path / "results.json", [], "--output"
    if case == "a folder":
        output.mkdir()
    elif case == "under a file":
        output = blocker / "eval" / "results.json"
    elif case == "unwritable":
        output = _unwritable_folder(tmp_path) / "eval" / "results.json"
    elif case == "markdown is a folder":
        output.with_suffix(".md").mkdir()
        flag = "Markdown report"
    elif case == "rerun under a file":
        extra, flag = ["--rerun", str(blocker / "eval.rrd")], "--rerun"
    elif case == "md":
        output = tmp_path / "results.md"
    code, _ = _run(tmp_path, "--baseline", "expert", *SMALL, *extra, output=output)
    error = _one_line_error(capsys)  # refused before any rollout, not when the results are written
    assert code == 2 and flag in error
    assert not [path for pattern in ("*.json", "*.md", "*.png") for path in tmp_path.rglob(pattern) if path.is_file()]


# ---------------------------------------------------------------------------------------------- 3. numbers


@pytest.mark.parametrize(
    "flag, value",
    [("--seed", "-5"), ("--episodes-per-variation", "0"), ("--workers", "0"), ("--rerun-episodes", "-1"), ("--max-steps", "0"),
     ("--seed", "five")],
)
def test_a_bad_number_is_one_line_naming_the_flag(tmp_path, capsys, flag, value):
    args = ["--baseline", "expert", "--task", "door", "--variations", "0", "--episodes-per-variation", "1", "--max-steps", "5"]
    code, output = _run(tmp_path, *args, flag, value)
    error = _one_line_error(capsys)
    assert code == 2 and f"argument {flag}:" in error and value in error
    assert not output.exists()


# ---------------------------------------------------------------------------------------------- 4. checkpoints


def _damage_safetensors_header(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[8:20] = b"#not json###"
    path.write_bytes(bytes(data))


@pytest.mark.parametrize(
    "damage, file",
    [
        (lambda folder: (folder / "policy_preprocessor.json").unlink(), "policy_preprocessor.json"),
        (lambda folder: (folder / "policy_postprocessor.json").unlink(), "policy_postprocessor.json"),
        (lambda folder: os.truncate(folder / "model.safetensors", 1_000_000), "model.safetensors"),
        (lambda folder: _damage_safetensors_header(folder / "model.safetensors"), "model.safetensors"),
        (lambda folder: (folder / "policy_preprocessor_step_3_normalizer_processor.safetensors").unlink(),
         "policy_preprocessor_step_3_normalizer_processor.safetensors"),
        (lambda folder: (folder / "config.json").unlink(), "config.json"),
    ],
    ids=["no preprocessor", "no postprocessor", "truncated weights", "damaged header", "no normalizer state", "no config"],
)
def test_an_incomplete_checkpoint_is_refused_before_rollouts(tmp_path, capsys, tiny_checkpoint, damage, file):
    checkpoint = tmp_path / "pretrained_model"
    shutil.copytree(tiny_checkpoint, checkpoint)
    damage(checkpoint)
    code, output = _run(tmp_path, f"--policy.path={checkpoint}", *SMALL)
    error = _one_line_error(capsys)
    assert code == 2 and str(checkpoint / file) in error
    assert "copy the whole pretrained_model folder" in error and "retrain" in error
    assert not output.exists()


# ---------------------------------------------------------------------------------------------- 5. demo videos


def _demo_dataset(tmp_path: Path) -> tuple[Path, Path]:
    from tests.helpers.evaluation import write_demo_dataset

    root = write_demo_dataset(tmp_path / "door_sawyer", "door", [0, 1])
    (video,) = (root / "videos").rglob("*.mp4")
    return root, video


def test_a_damaged_demo_video_is_named_before_rollouts(tmp_path, capsys, tiny_checkpoint):
    root, video = _demo_dataset(tmp_path)
    overwrite_middle(video)
    capsys.readouterr()  # what writing the dataset printed
    code, output = _run(tmp_path, f"--policy.path={tiny_checkpoint}", *SMALL, "--demo-dataset", str(root))
    error = _one_line_error(capsys)
    assert code == 2 and f"demo video {video} does not decode" in error and f"mosaic-data validate {root}" in error
    assert not output.exists()


def test_a_demo_video_missing_frames_is_named_before_rollouts(tmp_path, capsys, tiny_checkpoint):
    root, video = _demo_dataset(tmp_path)
    drop_last_frames(video, 2)  # the last episode (door variation 1) loses 2 of its 10 frames
    capsys.readouterr()  # what writing the dataset printed
    code, output = _run(tmp_path, f"--policy.path={tiny_checkpoint}", *SMALL[:2], "--variations", "1", *SMALL[4:],
                        "--demo-dataset", str(root))
    error = _one_line_error(capsys)
    assert code == 2 and f"demo video {video} decodes to 8 frames of episode 3, its metadata says 10" in error
    assert "mosaic-data validate" in error and not output.exists()


def test_a_demo_dataset_the_expert_does_not_use_is_said_to_be_unused(tmp_path, capsys):
    """The expert reads its goal from the simulator: the dataset is never decoded, so the run must not look as if it
    used (or vouched for) it, damaged as it is here."""
    root, video = _demo_dataset(tmp_path)
    overwrite_middle(video)
    capsys.readouterr()  # what writing the dataset printed
    code, output = _run(tmp_path, "--baseline", "expert", *SMALL, "--demo-dataset", str(root))
    warnings = [line for line in capsys.readouterr().err.splitlines() if "--demo-dataset" in line]
    assert code == 0 and output.exists()
    assert len(warnings) == 1 and warnings[0].startswith("mosaic-eval: warning:"), warnings
    assert f"--demo-dataset {root} is unused" in warnings[0] and "the expert baseline" in warnings[0], warnings


def test_a_video_that_fails_during_the_evaluation_is_named(tmp_path):
    """Damage found by the decoder in a worker (after the up-front check) names the file too."""
    from pipelines.evaluation.agents import EvaluationError
    from pipelines.evaluation.demo_sources import DatasetDemoSource

    root, video = _demo_dataset(tmp_path)
    source = DatasetDemoSource(root, (48, 88))
    overwrite_middle(video)
    with pytest.raises(EvaluationError, match=re.escape(f"demo video {video} (episode ")) as caught:
        for seed in range(8):  # either episode of either variation: some frames lie in the damaged part
            for variation in (0, 1):
                source.demonstration("door", variation, seed, None)
    assert "mosaic-data validate" in str(caught.value)


# ---------------------------------------------------------------------------------------------- 6. dataset names


def test_an_unknown_demo_dataset_names_how_mosaic_eval_finds_datasets(tmp_path, capsys):
    code, _ = _run(tmp_path, "--baseline", "untrained", *SMALL, "--demo-dataset", "mosaic/no_such_dataset")
    error = _one_line_error(capsys)
    assert code == 2 and "no LeRobot dataset at 'mosaic/no_such_dataset'" in error
    assert "HF_LEROBOT_HOME" in error and "--output-dir" not in error


def test_loading_a_checkpoint_prints_nothing_through_the_progress_bar(tmp_path, capfd, tiny_checkpoint):
    """LeRobot's from_pretrained prints "Loading weights from local directory" in every worker: one bar only."""
    code, _ = _run(tmp_path, f"--policy.path={tiny_checkpoint}", *SMALL)
    assert code == 0
    assert "Loading weights" not in capfd.readouterr().out


class _SlowToExit:
    """A worker process that has sent everything and closed its pipe, but has not exited yet (exitcode None)."""

    name, exitcode = "mosaic-eval-0", None

    def join(self, timeout=None):
        pass


class _KilledMidEpisode(_SlowToExit):
    exitcode = -9


def test_a_worker_still_exiting_after_its_last_episode_is_not_taken_for_dead():
    """A finished worker may take long to exit on a loaded machine: once it said "done" (the queue had nothing left
    for it), its closed pipe is not a death, whatever its exit code says yet."""
    from multiprocessing import Pipe

    from pipelines.evaluation.runner import _collect

    done_reader, done_writer = Pipe(duplex=False)
    busy_reader, busy_writer = Pipe(duplex=False)
    done_writer.send(("start", "episode 0"))
    done_writer.send(("result", "result 0"))
    done_writer.send(("done", None))
    done_writer.close()  # finished its share, still tearing down
    busy_writer.send(("start", "episode 1"))
    results = _collect([_SlowToExit(), _SlowToExit()], [done_reader, busy_reader], total=2)
    assert next(results) == "result 0"
    busy_writer.send(("result", "result 1"))
    assert list(results) == ["result 1"]


def test_a_worker_gone_between_episodes_without_saying_done_is_reported_dead():
    """Killed after its last result and before it took the next episode, still being torn down (no exit code yet):
    a death, although the other worker could run the rest of the queue."""
    from multiprocessing import Pipe

    from pipelines.evaluation.options import WorkerDied
    from pipelines.evaluation.runner import _collect

    gone_reader, gone_writer = Pipe(duplex=False)
    busy_reader, busy_writer = Pipe(duplex=False)
    gone_writer.send(("start", "episode 0"))
    gone_writer.send(("result", "result 0"))
    gone_writer.close()
    for episode in (1, 2):
        busy_writer.send(("start", f"episode {episode}"))
        busy_writer.send(("result", f"result {episode}"))
    with pytest.raises(WorkerDied, match="evaluation worker mosaic-eval-0 died"):
        list(_collect([_SlowToExit(), _SlowToExit()], [gone_reader, busy_reader], total=3))


def test_a_worker_gone_mid_episode_is_reported_dead():
    from multiprocessing import Pipe

    from pipelines.evaluation.options import WorkerDied
    from pipelines.evaluation.runner import _collect

    reader, writer = Pipe(duplex=False)
    writer.send(("start", None))
    writer.close()
    with pytest.raises(WorkerDied, match="died"):
        list(_collect([_KilledMidEpisode()], [reader], total=1))
