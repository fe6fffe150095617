"""Argument types shared by the command lines (``mosaic-data``, ``mosaic-eval``): one parsing, one error text."""

from __future__ import annotations

import argparse


def parse_int_list(text: str) -> list[int]:
    """``"0,3,5"`` -> ``[0, 3, 5]``."""
    try:
        return [int(part) for part in text.split(",") if part.strip() != ""]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers such as 0,3,5, got {text!r}") from None


def parse_image_size(text: str) -> tuple[int, int]:
    """``"100x180"`` -> ``(100, 180)`` (height, width)."""
    try:
        height, width = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HEIGHTxWIDTH such as 100x180, got {text!r}") from None
    if height < 16 or width < 16:
        raise argparse.ArgumentTypeError(f"images must be at least 16x16, got {text!r}")
    return height, width
