"""The same bad list or number gets the same one-line refusal from every command that takes it, naming the flag."""

from __future__ import annotations

import argparse

import pytest

from mosaic_data.cli import build_parser as mosaic_data_parser
from mosaic_data.cli_args import (
    MAX_EPISODES,
    MAX_IMAGE_SIDE,
    episode_count,
    non_negative_int,
    parse_image_size,
    parse_int_list,
    positive_int,
)
from pipelines.evaluation.cli import build_parser as mosaic_eval_parser

COMMANDS = {
    "experts": (mosaic_data_parser, ["experts", "--task", "door"]),
    "collect": (mosaic_data_parser, ["collect", "--task", "door"]),
    "mosaic-eval": (mosaic_eval_parser, ["--task", "door", "--baseline", "expert"]),
}


def _refusal(command: str, extra: list[str], capsys) -> str:
    build, base = COMMANDS[command]
    with pytest.raises(SystemExit) as exit_info:
        build().parse_args(base + extra)
    assert exit_info.value.code == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if "error:" in line]
    assert len(lines) == 1
    return lines[0].split("error: ", 1)[1]


@pytest.mark.parametrize("bad", [",", "0,0", "0,,1", "1,-2", "a"])
def test_bad_variation_lists_are_refused_with_the_same_words_everywhere(bad, capsys):
    messages = {command: _refusal(command, ["--variations", bad], capsys) for command in COMMANDS}
    assert len(set(messages.values())) == 1, messages
    message = messages["collect"]
    assert message.startswith("argument --variations: ") and repr(bad) in message


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_negative_seed_names_the_flag(command, capsys):
    assert _refusal(command, ["--seed", "-1"], capsys) == "argument --seed: expected an integer >= 0, got -1"


@pytest.mark.parametrize("command, flag", [("experts", "--episodes"), ("collect", "--episodes"), ("mosaic-eval", "--episodes-per-variation")])
def test_episode_counts_are_bounded(command, flag, capsys):
    expected = f"argument {flag}: expected an episode count from 1 to {MAX_EPISODES}, got 1000000000"
    assert _refusal(command, [flag, "1000000000"], capsys) == expected
    assert "got 0" in _refusal(command, [flag, "0"], capsys)


def test_good_values_parse():
    assert parse_int_list("0, 3,5") == [0, 3, 5]
    assert non_negative_int("0") == 0 and positive_int("2") == 2 and episode_count(str(MAX_EPISODES)) == MAX_EPISODES
    with pytest.raises(argparse.ArgumentTypeError):
        positive_int("0")


@pytest.mark.parametrize("command", ["collect", "mosaic-eval"])
@pytest.mark.parametrize("size", ["10000x10000", "100x9000", "8193x16"])
def test_image_sizes_beyond_the_renderer_are_refused_up_front(command, size, capsys):
    """A frame larger than the offscreen renderer holds is refused in one line by both commands, before any shard
    starts: nothing is left behind and no traceback is printed."""
    message = _refusal(command, ["--image-size", size], capsys)
    assert message == (
        f"argument --image-size: images must be at most {MAX_IMAGE_SIDE}x{MAX_IMAGE_SIDE} (the largest frame the "
        f"offscreen renderer holds), got {size!r}: the paper's size is 100x180"
    )


def test_the_largest_image_size_parses():
    assert parse_image_size(f"{MAX_IMAGE_SIDE}x{MAX_IMAGE_SIDE}") == (MAX_IMAGE_SIDE, MAX_IMAGE_SIDE)
    assert parse_image_size("16x8192") == (16, 8192)
