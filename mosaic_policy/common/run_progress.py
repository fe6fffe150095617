"""How far the current lerobot-train run has got, told by LeRobot itself and not read from its command line.

A policy is never told how long it will train, but lerobot-train builds the policy's scheduler preset with the
run's ``--steps`` (``scheduler.build(optimizer, num_training_steps)``), steps it after every optimiser step, saves
its state in every checkpoint and restores it on ``--resume``. The demo-conditioned policies' preset is a
constant learning rate (or a cosine decay over the run, ``--policy.lr_schedule=cosine``) through
:class:`RunProgressScheduler`, which remembers the run's length; a schedule that must end with training (MOSAIC's
EMA momentum) reads :func:`run_progress`. So fine-tuning a checkpoint (``--policy.path``, a new scheduler)
restarts such a schedule, and ``--resume`` continues it to the new ``--steps``.

lerobot-train builds one scheduler per process; the latest one built is the run's.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

from lerobot.optim.schedulers import LRSchedulerConfig
from torch.optim import Optimizer
from torch.optim.lr_scheduler import LambdaLR

_current: weakref.ref | None = None

LR_SCHEDULES = ("constant", "cosine")
"""``constant``: the optimiser's rate throughout (the paper). ``cosine``: half a cosine from it down to
``final_lr_ratio`` of it at the run's last step, the usual remedy for a noisy last iterate; docs/cpu_learning.md
measures what it does on door at the ``cpu`` experiment preset."""


class RunProgressScheduler(LambdaLR):
    """A learning rate that knows the run's length; ``last_epoch`` counts the optimiser steps taken."""

    def __init__(self, optimizer: Optimizer, total_steps: int, schedule: str = "constant", final_lr_ratio: float = 0.1):
        if schedule not in LR_SCHEDULES:
            raise ValueError(f"learning-rate schedule must be one of {LR_SCHEDULES}, got {schedule!r}")
        self.total_steps = max(1, int(total_steps))
        self.schedule = schedule
        self.final_lr_ratio = final_lr_ratio
        super().__init__(optimizer, self.lr_factor)

    def lr_factor(self, step: int) -> float:
        """Factor on the optimiser's learning rate at optimiser step ``step`` of this run."""
        if self.schedule == "constant":
            return 1.0
        progress = min(step, self.total_steps) / self.total_steps
        return self.final_lr_ratio + (1.0 - self.final_lr_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))

    def load_state_dict(self, state_dict: dict) -> None:
        """Restore the step count (``--resume``); the length stays this run's ``--steps``."""
        total = self.total_steps
        super().load_state_dict(state_dict)
        self.total_steps = total


@LRSchedulerConfig.register_subclass("run_progress")
@dataclass
class RunProgressSchedulerConfig(LRSchedulerConfig):
    """``--scheduler.type=run_progress``: constant or cosine-decayed learning rate; schedules inside the policy follow
    the run."""

    num_warmup_steps: int | None = None
    schedule: str = "constant"
    final_lr_ratio: float = 0.1

    def build(self, optimizer: Optimizer, num_training_steps: int) -> RunProgressScheduler:
        global _current
        scheduler = RunProgressScheduler(optimizer, num_training_steps, self.schedule, self.final_lr_ratio)
        _current = weakref.ref(scheduler)
        return scheduler


def run_progress() -> tuple[int, int] | None:
    """(optimiser steps taken, total steps) of the current lerobot-train run; None outside one."""
    scheduler = _current() if _current is not None else None
    if scheduler is None:
        return None
    return int(scheduler.last_epoch), scheduler.total_steps
