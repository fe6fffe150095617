"""Choices, defaults and the errors of ``mosaic-eval``, importable without torch, LeRobot or the simulator.

``mosaic-eval --help`` (and a bad option) needs only these; the modules that use them (agents, rollouts)
import them from here, so there is one definition and the help costs no heavy import.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

from mosaic_data.cli_args import positive_int
from mosaic_data.constants import EVAL_BASE_SEED  # noqa: F401  (mosaic-eval's default --seed; standard library only)

BASELINES: tuple[str, ...] = ("expert", "untrained")
"""Sanity rows the evaluation can produce without a checkpoint."""


def parse_bool(text: str) -> bool:
    if text.lower() in ("true", "1", "yes"):
        return True
    if text.lower() in ("false", "0", "no"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


POLICY_OPTIONS: dict[str, tuple[Callable[[str], object], str]] = {
    "n_action_steps": (positive_int, "targets executed per query, the first of each predicted chunk (MOSAIC and "
                       "baselines: 1..action_chunk; ACT: 1..chunk_size)"),
    "temporal_ensemble_coeff": (float, "query every step and average the chunks that cover it, weight exp(-coeff * "
                                "age) (ACT's temporal ensembling)"),
    "action_sampling": (str, "mode or sample: how a target is drawn from the head's distribution (MOSAIC and baselines)"),
    "act_with_weight_average": (parse_bool, "true or false: act with the checkpoint's averaged weights or its trained ones"),
}
"""Inference options ``mosaic-eval --policy.NAME=VALUE`` sets on every checkpoint's config (as lerobot-eval's
``--policy.NAME``): name -> (argument type, help). The same trained weights rolled out another way, so a comparison
holds the training run fixed."""


def add_policy_option_arguments(parser: argparse.ArgumentParser, help_suffix: str = "") -> None:
    """One ``--policy.NAME`` argument per POLICY_OPTIONS entry (read back with :func:`policy_options`)."""
    for name, (value_type, help_text) in POLICY_OPTIONS.items():
        parser.add_argument(
            f"--policy.{name}", dest=f"policy_{name}", type=value_type, default=None, metavar="V", help=help_text + help_suffix
        )


def policy_options(args: argparse.Namespace) -> dict[str, object]:
    """The ``--policy.NAME`` inference options given on the command line (name -> value)."""
    return {name: getattr(args, f"policy_{name}") for name in POLICY_OPTIONS if getattr(args, f"policy_{name}", None) is not None}


POLL_S = 0.5
"""How often an executor (local worker processes or Ray) looks for finished episodes and dead workers while it waits."""


class EvaluationError(ValueError):
    """Bad evaluation input (checkpoint, task, variations, demo dataset): the message names the fix."""


class WorkerDied(RuntimeError):
    """An evaluation worker ended without reporting its episode (killed, e.g. by the out-of-memory killer, crashed,
    or a Ray worker or node lost)."""


def check_arguments(args: argparse.Namespace) -> dict[str, list[int]]:
    """Task -> variations of ``--task`` and ``--variations``, after the checks that need no checkpoint: task names,
    variations, what to evaluate and the executor's options. Plain data only (the suite's table), so a typo is
    reported before torch, LeRobot or the simulator load, which takes seconds."""
    from mosaic_data.cli_args import ray_address_problem
    from mosaic_data.tasks import select_variations  # the table only, not the simulator

    try:
        tasks = select_variations(args.task, args.variations)
    except ValueError as error:
        raise EvaluationError(str(error)) from None
    if (problem := ray_address_problem(args.executor, args.ray_address)) is not None:
        raise EvaluationError(problem)
    if not args.policy_paths and not args.baseline:
        raise EvaluationError("nothing to evaluate: pass --policy.path=<checkpoint> and/or --baseline expert|untrained")
    return tasks
