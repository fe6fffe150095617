"""What lerobot-train gives every demonstration-conditioned policy, in one place: paired demonstrator frames and
the loss weights of a batch.

lerobot-train hands a policy its agent dataset's metadata (``make_policy(..., ds_meta=...)``) and batches of
agent samples carrying their LeRobot task string (the variation) and episode index. :class:`DemoConditioning`
turns those into what the model needs, with no flag beyond ``--policy.demo_repo_id``:

- the demonstrator frames of every sample (:class:`~.paired_sampling.PairedDemoSampler`: same variation,
  another instance, first/last/middle-segment frames, restricted to the instances the run trains on);
- per-sample weights that average the loss per variation, then per variation of a task, then over tasks (the
  paper's rule), whatever the batch mix. A variation's task comes from the suite's plain-data table
  (:mod:`mosaic_data.tasks.spec`, no simulator); strings not found there count as one unnamed task.

Under ``accelerate launch`` every training process builds its own conditioning: its sampler pairs the samples
of the process's shard of the batch, draws from its own random stream (seeded with the process's rank) and
decodes with its share of the machine's cores (:mod:`.distributed`).

Policies are models: they call this, they never read the command line or import the simulator.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import torch
from torch import Tensor

from mosaic_data.constants import DEMO_FRAMES_KEY

from .distributed import demo_threads_per_process, gather_from_ranks, process_rank
from .paired_sampling import PairedDemoSampler


def to_float_frames(frames: Tensor | np.ndarray) -> Tensor:
    """Frames as float in [0, 1], channels first ((..., H, W, 3) uint8 or (..., 3, H, W) float accepted)."""
    frames = torch.as_tensor(frames)
    if frames.shape[-1] == 3 and frames.shape[-3] != 3:
        frames = frames.movedim(-1, -3)
    if frames.dtype == torch.uint8:
        return frames.float() / 255.0
    return frames.float()


def balanced_sample_weights(variations: list[str], device: torch.device | str = "cpu") -> Tensor:
    """Weights summing to 1: mean over the samples of a variation, then over the variations of a task, then
    over tasks."""
    from mosaic_data.tasks.spec import task_of_variation

    task_of = task_of_variation()
    tasks = [task_of.get(v, "") for v in variations]
    per_variation = Counter(variations)
    variations_per_task = Counter(dict(zip(variations, tasks, strict=True)).values())
    n_tasks = len(variations_per_task)
    weights = [
        1.0 / (n_tasks * variations_per_task[t] * per_variation[v]) for v, t in zip(variations, tasks, strict=True)
    ]
    return torch.tensor(weights, device=device)


class DemoConditioning:
    """Demonstrator frames and loss weights for the batches of one training run (see the module docstring)."""

    def __init__(self, sampler: PairedDemoSampler | None, balance_loss: bool = True):
        self.sampler = sampler
        self.balance_loss = balance_loss

    @classmethod
    def for_training(cls, config, dataset_meta, agent_episodes: list[int] | None = None) -> DemoConditioning:
        """The conditioning of a lerobot-train run on ``dataset_meta``'s agent dataset (``config`` is a
        :class:`~.configuration_demo.DemoConditionedConfig`)."""
        if config.demo_repo_id is None:
            raise ValueError(
                f"{config.type} trains on agent samples paired with demonstrator videos: pass "
                "--policy.demo_repo_id=<demonstrator dataset, e.g. mosaic/door_sawyer> (and --policy.demo_root if local)."
            )
        sampler = PairedDemoSampler(
            config.demo_repo_id,
            config.demo_root,
            config.camera_key,
            config.n_demo_frames,
            agent_meta=dataset_meta,
            agent_episodes=agent_episodes,
            threads=demo_threads_per_process(config.demo_loader_threads),
            prefetch_batches=config.demo_prefetch_batches,
            process_index=process_rank(),
        )
        return cls(sampler, config.balance_loss)

    def demo_frames(self, batch: dict[str, Any]) -> Tensor:
        """(B, n_demo_frames, 3, H, W) float frames: the batch's own ``demo_frames`` if it has them, else paired."""
        if DEMO_FRAMES_KEY in batch:
            return to_float_frames(batch[DEMO_FRAMES_KEY])
        if self.sampler is None:
            raise RuntimeError(
                f"no demonstrator frames: pass batch['{DEMO_FRAMES_KEY}'] or build the policy with dataset_meta and "
                "config.demo_repo_id (lerobot-train does: --policy.demo_repo_id=...)."
            )
        tasks = batch.get("task")
        if tasks is None:
            raise RuntimeError("the batch has no 'task' strings to pair demonstrations by variation.")
        episodes = batch.get("episode_index")
        episodes = [int(e) for e in episodes.reshape(-1).tolist()] if episodes is not None else None
        return self.sampler.sample(list(tasks), episodes).float() / 255.0

    def sample_weights(self, batch: dict[str, Any], n_samples: int, device, training: bool = False) -> Tensor:
        """Loss weights of the batch's samples, summing to 1 (balanced per variation and task: see the module).

        Training in several processes (``training`` and a distributed run), the balance is the one of the global
        batch, every rank's shard together, as one process training on that batch would weigh it: each rank gets
        its samples' weights times the number of ranks, since DDP averages the ranks' gradients."""
        if not self.balance_loss or "task" not in batch:
            return torch.full((n_samples,), 1.0 / n_samples, device=device)
        tasks = list(batch["task"])
        shards = gather_from_ranks(tasks) if training else None
        if shards is None:
            return balanced_sample_weights(tasks, device)
        start = sum(len(shard) for shard in shards[: process_rank()])
        weights = balanced_sample_weights([t for shard in shards for t in shard], device)
        return weights[start : start + len(tasks)] * len(shards)

    @property
    def last_wait_s(self) -> float | None:
        return self.sampler.last_wait_s if self.sampler is not None else None

    def close(self) -> None:
        if self.sampler is not None:
            self.sampler.close()
