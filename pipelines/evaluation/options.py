"""Choices, defaults and the input error of ``mosaic-eval``, importable without torch, LeRobot or the simulator.

``mosaic-eval --help`` (and a bad option) needs only these; the modules that use them (agents, rollouts)
import them from here, so there is one definition and the help costs no heavy import.
"""

from __future__ import annotations

from mosaic_data.constants import EVAL_BASE_SEED  # noqa: F401  (mosaic-eval's default --seed; standard library only)

BASELINES: tuple[str, ...] = ("expert", "untrained")
"""Sanity rows the evaluation can produce without a checkpoint."""


class EvaluationError(ValueError):
    """Bad evaluation input (checkpoint, task, variations, demo dataset): the message names the fix."""
