"""The exit contract every MOSAIC command line shares: SIGTERM stops a command as Ctrl-C does, with status 143."""

import os
import signal

from mosaic_data.exit_status import INTERRUPTED, TERMINATED, ExitContract, Terminated

CONTRACT = ExitContract("mosaic-test", interrupted_line="{command}: interrupted; run it again to resume")


def _stopped_by_sigterm() -> int:
    try:
        os.kill(os.getpid(), signal.SIGTERM)
        signal.pause()  # the handler raises before this returns; the line is never passed otherwise
    except KeyboardInterrupt as stop:  # the clean-up path Ctrl-C takes runs for SIGTERM too
        assert isinstance(stop, Terminated)
        raise
    return 0


def test_sigterm_stops_a_command_as_ctrl_c_does_with_status_143(capsys):
    before = signal.getsignal(signal.SIGTERM)
    assert CONTRACT.run(_stopped_by_sigterm) == TERMINATED == 143
    assert capsys.readouterr().err.strip() == "mosaic-test: interrupted; run it again to resume"
    assert signal.getsignal(signal.SIGTERM) is before  # the handler lives only while the command runs


def test_ctrl_c_keeps_status_130(capsys):
    def interrupted() -> int:
        raise KeyboardInterrupt

    assert CONTRACT.run(interrupted) == INTERRUPTED == 130
    assert "interrupted" in capsys.readouterr().err


def test_an_ignored_sigterm_stays_ignored():
    before = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        def ignored() -> int:
            os.kill(os.getpid(), signal.SIGTERM)
            return 0

        assert CONTRACT.run(ignored) == 0
    finally:
        signal.signal(signal.SIGTERM, before)
