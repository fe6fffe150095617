"""Kill one worker of a running command as the out-of-memory killer would, from a process of its own.

``python -m tests.helpers.worker_killer PID LOG PLANNED REPORT`` waits until the progress bar that command ``PID``
writes to ``LOG`` shows a finished episode of ``PLANNED``, SIGKILLs the first of its spawned worker processes, waits
for the command to end and writes what it saw to ``REPORT`` (JSON). A test that did this itself depended on its own
process being scheduled: in full suites on clean clones the test's polling loop was seen to stall for minutes while
the evaluation ran on (its 400- and then 2000-episode plans ran to the end before the test saw the first episode),
and the finished evaluation's workers then took both cores from the tests beside it. A small process that does only
this does not wait on the test's interpreter, and a deadline ends the command if the kill never comes.
"""

from __future__ import annotations

import json
import os
import re
import signal
import sys
import time
from pathlib import Path

from tests.helpers.processes import alive, children, command_line, kill_tree

FIRST_EPISODE_DEADLINE_S = 300.0
"""No finished episode by then: the command is killed and the report says so."""
DEATH_WAIT_S = 30.0
STOP_WAIT_S = 120.0
POLL_S = 0.05


def finished_episodes(log: Path, planned: int) -> int:
    counts = re.findall(rb"\| *(\d+)/%d" % planned, log.read_bytes())
    return max((int(count) for count in counts), default=0)


def log_tail(log: Path) -> str:
    return log.read_bytes()[-2000:].decode(errors="replace")


def watch(pid: int, log: Path, planned: int) -> dict:
    started = time.monotonic()
    while finished_episodes(log, planned) < 1:
        if not alive(pid):
            return {"error": "ended before any episode finished", "log_tail": log_tail(log)}
        if time.monotonic() > started + FIRST_EPISODE_DEADLINE_S:
            kill_tree(pid)
            return {"error": f"no episode finished within {FIRST_EPISODE_DEADLINE_S:g} s", "log_tail": log_tail(log)}
        time.sleep(POLL_S)
    first_episode_in = time.monotonic() - started
    workers = [child for child in children(pid) if "spawn_main" in command_line(child) and alive(child)]
    if len(workers) != 2:
        seen = [(command_line(child), alive(child)) for child in children(pid)]
        kill_tree(pid)
        return {"error": f"expected 2 workers, found {seen}", "log_tail": log_tail(log)}
    victim, victim_command = workers[0], command_line(workers[0])
    episodes_before_kill = finished_episodes(log, planned)
    os.kill(victim, signal.SIGKILL)
    killed_at = time.monotonic()
    while alive(victim) and time.monotonic() < killed_at + DEATH_WAIT_S:
        time.sleep(POLL_S)
    while alive(pid) and time.monotonic() < killed_at + STOP_WAIT_S:
        time.sleep(POLL_S)
    return {
        "first_episode_in_s": round(first_episode_in, 1),
        "episodes_before_kill": episodes_before_kill,
        "workers": workers,
        "killed": victim,
        "killed_command": victim_command,
        "victim_died": not alive(victim),
        "stopped_after_kill_s": None if alive(pid) else round(time.monotonic() - killed_at, 1),
    }


def main(argv: list[str]) -> None:
    pid, log, planned, report = int(argv[0]), Path(argv[1]), int(argv[2]), Path(argv[3])
    report.write_text(json.dumps(watch(pid, log, planned)))


if __name__ == "__main__":
    main(sys.argv[1:])
