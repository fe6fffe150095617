"""The collection tests' image size, the ``mosaic-data`` command run in-process, and SIGINT for child processes."""

from __future__ import annotations

import signal

HEIGHT, WIDTH = 56, 96
"""Small images keep encoding cheap; the simulator, expert and horizon are the real ones."""
TEST_IMAGE_SIZE = f"{HEIGHT}x{WIDTH}"
"""The same size as ``--image-size`` takes it."""


def ctrl_c_reaches_it() -> None:
    """``preexec_fn`` of a child process a test interrupts with SIGINT. A shell running the suite as a background job
    (``bash .ci/run &``, ``nohup ... &``) starts its commands with SIGINT ignored, which every child inherits; Python
    then never raises KeyboardInterrupt and the child goes on as if Ctrl-C had not been pressed. The child gets the
    default disposition back, as in a terminal."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_cli(*args: str) -> int:
    """``mosaic-data <args>`` in this process; returns the exit status."""
    from mosaic_data.cli import main

    return main(list(args))
