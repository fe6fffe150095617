"""The one check every bad-input test makes: the command printed exactly one error line, naming what it must."""

from __future__ import annotations


def one_line_error(capsys, *words: str, command: str = "mosaic-data") -> str:
    """The error line on stderr; fails unless it is one line starting ``<command>: error:`` holding every word."""
    error = capsys.readouterr().err.strip()
    assert error.startswith(f"{command}: error:") and "\n" not in error, error
    for word in words:
        assert word in error, error
    return error
