"""Choices, defaults and the input error of ``mosaic-eval``, importable without torch, LeRobot or the simulator.

``mosaic-eval --help`` (and a bad option) needs only these; the modules that use them (agents, rollouts)
import them from here, so there is one definition and the help costs no heavy import.
"""

from __future__ import annotations

BASELINES: tuple[str, ...] = ("expert", "untrained")
"""Sanity rows the evaluation can produce without a checkpoint."""

EVAL_BASE_SEED = 1_000_000_000
"""Default base seed of the evaluation's instances, far from the collection's seeds."""


class EvaluationError(ValueError):
    """Bad evaluation input (checkpoint, task, variations, demo dataset): the message names the fix."""
