"""Argument types shared by the command lines (``mosaic-data``, ``mosaic-eval``): one parsing, one error text.

argparse prefixes a type's error with the flag (``argument --seed: ...``), so every message here names the flag
without the type knowing it, and the same bad value gets the same words from every command.
"""

from __future__ import annotations

import argparse

class OneLineErrorParser(argparse.ArgumentParser):
    """argparse that reports a bad argument as our commands report every other bad input: one line
    ``<command>: error: argument --flag: ...`` on stderr and exit status 2, without the usage block
    (``--help`` still shows it). Subcommand parsers inherit the class; the line names the command, not the
    subcommand, so every error of ``mosaic-data`` starts with ``mosaic-data: error:``."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog.split()[0]}: error: {message}\n")


MAX_EPISODES = 10_000
"""Upper bound for per-variation episode counts: a typo like 1000000000 would otherwise run for years."""


def parse_int_list(text: str) -> list[int]:
    """``"0,3,5"`` -> ``[0, 3, 5]``; empty items (``","``, ``"0,,1"``), repeats (``"0,0"``) and negatives are refused."""
    example = "expected comma-separated distinct non-negative integers such as 0,3,5"
    parts = [part.strip() for part in text.split(",")]
    if any(part == "" for part in parts):
        raise argparse.ArgumentTypeError(f"{example}, got {text!r} (an empty item)")
    try:
        values = [int(part) for part in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{example}, got {text!r}") from None
    if any(value < 0 for value in values):
        raise argparse.ArgumentTypeError(f"{example}, got {text!r} (a negative value)")
    repeated = sorted({value for value in values if values.count(value) > 1})
    if repeated:
        raise argparse.ArgumentTypeError(f"{example}, got {text!r} ({', '.join(map(str, repeated))} repeated)")
    return values


def _bounded_int(text: str, low: int, high: int | None, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if value < low or (high is not None and value > high):
        raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
    return value


def non_negative_int(text: str) -> int:
    """Seeds and indices: ``>= 0`` (simulator seeds and episode indices are never negative)."""
    return _bounded_int(text, 0, None, "an integer >= 0")


def positive_int(text: str) -> int:
    """Counts such as workers and steps: ``>= 1``."""
    return _bounded_int(text, 1, None, "an integer >= 1")


def episode_count(text: str) -> int:
    """Episodes per variation: ``1 .. MAX_EPISODES``."""
    return _bounded_int(text, 1, MAX_EPISODES, f"an episode count from 1 to {MAX_EPISODES}")


MIN_IMAGE_SIDE = 16
MAX_IMAGE_SIDE = 8192
"""Largest camera height and width. The tasks size MuJoCo's offscreen framebuffer to the frame
(``size_render_buffers``: ``offwidth`` x ``offheight``, 4x multisampled), and Mesa's software renderer (llvmpipe,
what headless EGL falls back to) holds at most 1 GiB per buffer: 8192x8192 renders, 10000x10000 fails with
"Offscreen framebuffer is not complete" inside the first worker, after the imports and the scene build."""


def parse_image_size(text: str) -> tuple[int, int]:
    """``"100x180"`` -> ``(100, 180)`` (height, width), each side in ``MIN_IMAGE_SIDE .. MAX_IMAGE_SIDE``."""
    try:
        height, width = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HEIGHTxWIDTH such as 100x180, got {text!r}") from None
    if height < MIN_IMAGE_SIDE or width < MIN_IMAGE_SIDE:
        raise argparse.ArgumentTypeError(f"images must be at least {MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE}, got {text!r}")
    if height > MAX_IMAGE_SIDE or width > MAX_IMAGE_SIDE:
        raise argparse.ArgumentTypeError(
            f"images must be at most {MAX_IMAGE_SIDE}x{MAX_IMAGE_SIDE} (the largest frame the offscreen renderer "
            f"holds), got {text!r}: the paper's size is 100x180"
        )
    return height, width


def action_noise(text: str):
    """``--action-noise POS_STD_M[,ROT_STD_RAD]`` -> :class:`mosaic_data.action_noise.ActionNoise`, or None for zero."""
    from mosaic_data.action_noise import parse_action_noise  # numpy only

    try:
        return parse_action_noise(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def ray_address_problem(executor: str, ray_address: str | None) -> str | None:
    """Why ``--ray-address`` does not fit ``--executor`` (one line naming the fix), or None; both commands check it."""
    if ray_address is None:
        return None
    if executor != "ray":
        return "--ray-address needs --executor ray"
    if not ray_address.strip():
        return "--ray-address is empty: give the cluster's address, e.g. 'auto' or 'head-node:6379', or leave it out"
    return None


def add_executor_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """``--executor`` and ``--ray-address``, shared by ``mosaic-data collect`` and ``mosaic-eval``."""
    parser.add_argument(
        "--executor", choices=("local", "ray"), default="local",
        help=f"where the {what} run: 'local' processes on this machine, or 'ray' tasks on a Ray cluster (the same "
        "results either way)",
    )
    parser.add_argument(
        "--ray-address", default=None, metavar="ADDR",
        help="Ray cluster to use with --executor ray, e.g. 'auto' or 'head-node:6379'; None starts Ray on this machine",
    )
