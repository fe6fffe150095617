"""How every MOSAIC command line ends (``mosaic-data``, ``mosaic-eval``, ``mosaic-experiment``): one contract.

Exit status 0 when the command did its work, 2 on bad input (refused with one line that names the fix, argparse's
errors included), 1 when the work failed (an expert gave up, a worker died, a stage's command failed), 130 when
interrupted (Ctrl-C) and 143 when stopped by SIGTERM (``kill PID``, a job scheduler's stop), as a shell reports a
process ended by those signals. SIGTERM stops a command the way Ctrl-C does (:class:`Terminated`): its workers and
the command a stage runs are stopped and what finished is kept, instead of the process vanishing and leaving them
running. Each command says which of its exceptions
are bad input and which are failures (:class:`ExitContract`); any other exception is a bug and ends with its
traceback. Standard library only: the command lines import it before their heavy imports.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

SUCCESS = 0
FAILURE = 1
BAD_INPUT = 2
INTERRUPTED = 130
TERMINATED = 128 + signal.SIGTERM


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread while a command runs: a KeyboardInterrupt, so every clean-up path Ctrl-C
    takes runs for it too."""


def interrupted_status(error: KeyboardInterrupt) -> int:
    """The exit status of a command stopped by ``error``: 143 for SIGTERM, 130 for Ctrl-C."""
    return TERMINATED if isinstance(error, Terminated) else INTERRUPTED


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block SIGTERM raises :class:`Terminated` in the main thread. Nothing changes outside the main
    thread (a handler can only be set there) or when SIGTERM is ignored (the caller's choice)."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGTERM) == signal.SIG_IGN:
        yield
        return

    def stop(signum, frame) -> None:
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class Stopped(Exception):
    """The command stops with ``code``; ``message`` follows the command's name on its last line (used where the
    line says more than the error: what was kept, how to resume)."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


@dataclass(frozen=True)
class ExitContract:
    """One command's exit statuses and the message line of each; ``{command}`` and ``{error}`` in a line are the
    command's name and the exception's text."""

    command: str
    bad_input: tuple[type[BaseException], ...] = ()
    failure: tuple[type[BaseException], ...] = ()
    bad_input_line: str = "{command}: error: {error}"
    failure_line: str = "{command}: error: {error}"
    interrupted_line: str = "{command}: interrupted"

    def status_of(self, error: BaseException) -> tuple[int, str] | None:
        """``(exit status, message)`` for ``error``, or None when the contract does not cover it (a bug)."""
        if isinstance(error, Stopped):
            return error.code, f"{self.command}: {error.message}"
        if isinstance(error, KeyboardInterrupt):
            return interrupted_status(error), self.interrupted_line.format(command=self.command)
        if isinstance(error, self.bad_input):
            return BAD_INPUT, self.bad_input_line.format(command=self.command, error=error)
        if isinstance(error, self.failure):
            return FAILURE, self.failure_line.format(command=self.command, error=error)
        return None

    def run(self, action: Callable[[], int]) -> int:
        """``action()``'s status; an error the contract covers prints its message on stderr and gives its status.
        SIGTERM stops ``action`` as Ctrl-C does."""
        try:
            with sigterm_as_interrupt():
                return action()
        except (Exception, KeyboardInterrupt) as error:
            status = self.status_of(error)
            if status is None:
                raise
            code, message = status
            print(message, file=sys.stderr)
            return code

    def main(self, parser: argparse.ArgumentParser, argv: list[str] | None, action: Callable[[argparse.Namespace], int]) -> int:
        """Parse ``argv`` and run ``action`` on the arguments. A bad argument (the parser printed its line) and
        ``--help`` give the parser's status instead of raising ``SystemExit``, as every other error does."""
        try:
            args = parser.parse_args(argv)
        except SystemExit as exit_request:
            return exit_request.code if isinstance(exit_request.code, int) else SUCCESS
        return self.run(lambda: action(args))
