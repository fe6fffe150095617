"""Running processes as Linux's /proc shows them: the tests that stop commands check which processes are left."""

from __future__ import annotations

import os
import signal
from pathlib import Path


def command_line(pid: int) -> str:
    """The process's command line, arguments joined by spaces; "" once it has ended."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def running_command_lines() -> dict[int, str]:
    """pid -> command line of every process running now (those that end while being read are left out)."""
    lines = {int(entry.name): command_line(int(entry.name)) for entry in Path("/proc").iterdir() if entry.name.isdigit()}
    return {pid: line for pid, line in lines.items() if line}


def alive(pid: int) -> bool:
    """Running, not a zombie waiting to be reaped."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def children(pid: int) -> list[int]:
    """The process's child processes; [] once it has ended."""
    try:
        return [int(child) for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def kill_tree(pid: int) -> None:
    """SIGKILL the process and its children (those that already ended are skipped)."""
    for process in [*children(pid), pid]:
        try:
            os.kill(process, signal.SIGKILL)
        except OSError:
            pass
