"""A recipe is a plan of stages, each one shipped command (``mosaic-data``, ``lerobot-train``, ``mosaic-eval``).

Every stage keeps, under ``DIR/stages/<key>/``, its command line (``command.txt``), its output (``log.txt``) and,
once it has finished, ``done.json``. Running a recipe again skips the finished stages, so a killed or interrupted
run resumes with the stage it was in: a collection resumes its own shards, a training run resumes from its last
checkpoint with ``lerobot-train --resume=true`` (or restarts when it had saved none), an evaluation reruns.
Stopping a recipe (Ctrl-C, or SIGTERM as ``kill`` and job schedulers send) stops the command of its running stage
too, so no stage goes on writing into the folder after the recipe has ended.
"""

from __future__ import annotations

import fcntl
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from mosaic_data.exit_status import Terminated

from .presets import ExperimentError


@dataclass(frozen=True)
class Stage:
    """One command of a plan. ``output`` is what it makes (a dataset, a training run folder, a results file)."""

    key: str  # unique in the plan, also its folder under DIR/stages
    kind: str  # collect | merge | train | evaluate
    command: tuple[str, ...]
    output: Path
    title: str

    def shell_line(self) -> str:
        """The command as a user would type it."""
        return shlex.join(self.command)


def stage_folder(output_dir: Path, stage: Stage) -> Path:
    return output_dir / "stages" / stage.key


def is_done(output_dir: Path, stage: Stage) -> bool:
    return (stage_folder(output_dir, stage) / "done.json").is_file()


def _executable(name: str) -> str:
    """A console script of this environment (the venv's, whatever PATH says), else the name on PATH."""
    candidate = Path(sys.executable).parent / name
    return str(candidate) if candidate.exists() else name


def resume_command(stage: Stage) -> tuple[str, ...]:
    """The command that continues a stage a kill interrupted.

    A training run with a saved checkpoint resumes from it (lerobot-train restores weights, optimizer, scheduler
    and step); one that saved nothing starts again in an empty folder. A merge replaces what it half built.
    """
    if stage.kind == "train" and stage.output.exists():
        last = stage.output / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
        if last.is_file():
            return ("lerobot-train", "--resume=true", f"--config_path={last}")
        shutil.rmtree(stage.output)
    if stage.kind == "merge" and stage.output.exists() and "--overwrite" not in stage.command:
        return (*stage.command, "--overwrite")
    return stage.command


class StageFailed(RuntimeError):
    """A stage's command exited with an error; the message names its log."""


@contextmanager
def experiment_lock(output_dir: Path) -> Iterator[None]:
    """One mosaic-experiment at a time per folder: two would run the same stages into the same files."""
    output_dir.mkdir(parents=True, exist_ok=True)
    with (output_dir / ".lock").open("w") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ExperimentError(
                f"another mosaic-experiment is running in {output_dir}: wait for it, or use another --output"
            ) from None
        yield


def run_stage(output_dir: Path, stage: Stage, resume: bool) -> float:
    """Run ``stage`` (its resume form when ``resume``); seconds taken. StageFailed on a non-zero exit."""
    folder = stage_folder(output_dir, stage)
    folder.mkdir(parents=True, exist_ok=True)
    command = resume_command(stage) if resume else stage.command
    (folder / "command.txt").write_text(shlex.join(command) + "\n")
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    start = time.perf_counter()
    with (folder / "log.txt").open("a") as log:
        log.write(f"$ {shlex.join(command)}\n")
        log.flush()
        process = subprocess.Popen([_executable(command[0]), *command[1:]], stdout=log, stderr=subprocess.STDOUT, env=env)
        try:
            returncode = process.wait()
        except KeyboardInterrupt as stop:  # Ctrl-C (the child got it too: same process group), or SIGTERM to us alone
            # The child stops the same way: SIGTERM also ends a child that ignores SIGINT (a background job's does).
            process.send_signal(signal.SIGTERM if isinstance(stop, Terminated) else signal.SIGINT)
            process.wait()
            raise
    seconds = time.perf_counter() - start
    if returncode != 0:
        tail = "".join((folder / "log.txt").read_text().splitlines(keepends=True)[-12:])
        raise StageFailed(f"{tail}\nstage {stage.key} failed (`{command[0]}` exit {returncode}); log: {folder / 'log.txt'}")
    done = {"command": shlex.join(stage.command), "ran": shlex.join(command), "seconds": round(seconds, 2),
            "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    (folder / "done.json").write_text(json.dumps(done, indent=2))
    return seconds


def stage_seconds(output_dir: Path, stage: Stage) -> float | None:
    """How long a finished stage took (its done.json), None when it has not finished."""
    path = stage_folder(output_dir, stage) / "done.json"
    return json.loads(path.read_text())["seconds"] if path.is_file() else None
