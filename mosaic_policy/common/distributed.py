"""What a demonstration-conditioned policy does differently when lerobot-train runs as several processes.

``accelerate launch --num_processes N ... lerobot-train`` starts N processes (ranks); each builds its own policy,
its own demonstrator sampler and gets its own shard of every global batch (accelerate's ``BatchSamplerShard``).
DDP keeps the trainable weights identical (gradients are averaged before the optimizer step) and, before every
forward, copies rank 0's buffers to the other ranks. What it does not do, and this module does:

- :func:`process_rank` / :func:`local_world_size`: which rank this process is, how many share the machine;
- :func:`demo_threads_per_process`: the demonstrator decode threads of one process, so that N processes on one
  machine do not start N times the threads its cores can run;
- :func:`average_batchnorm_statistics`: BatchNorm running statistics averaged over the ranks after every
  optimizer step. Without it each rank updates them from its own shard only, the ranks' copies differ after
  every step and DDP keeps rank 0's: the statistics the policy acts with (and MOSAIC's EMA target copies) would
  come from 1/N of the samples, and the ranks' final states would differ;
- :func:`gather_from_ranks`: what every rank holds, for rules over the global batch (the loss balancing per
  variation and task: over one rank's shard it would weight the samples differently from the same batch in one
  process);
- :func:`rank_random_generators`: different random streams per rank. lerobot-train seeds every rank with the
  same ``--seed``, so every rank would draw the same augmentations (crops, jitter, blur), contrastive positives
  and dropout masks for its i-th sample as every other rank.

Outside a distributed run (one process, tests, inference) every function is a no-op.
"""

from __future__ import annotations

import os

import numpy as np
import torch
from torch import nn


def _distributed() -> bool:
    return torch.distributed.is_available() and torch.distributed.is_initialized()


def process_rank() -> int:
    """This process's global rank (0 outside a distributed run)."""
    if _distributed():
        return torch.distributed.get_rank()
    return int(os.environ.get("RANK", "0"))


def local_world_size() -> int:
    """Training processes on this machine (torchrun / accelerate launch set LOCAL_WORLD_SIZE)."""
    return max(1, int(os.environ.get("LOCAL_WORLD_SIZE", "1")))


def usable_cpus() -> int:
    """CPU cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def demo_threads_per_process(requested: int) -> int:
    """Demonstrator decode threads of this process: ``requested`` (``--policy.demo_loader_threads``), at most
    the machine's cores shared among its training processes, at least 1 (0 stays 0: synchronous decoding)."""
    n_local = local_world_size()
    if requested <= 0 or n_local <= 1:
        return requested
    return max(1, min(requested, usable_cpus() // n_local))


def gather_from_ranks(obj) -> list | None:
    """Every rank's ``obj`` in rank order (a collective: every rank must call it), None outside a distributed run."""
    if not _distributed() or torch.distributed.get_world_size() < 2:
        return None
    gathered: list = [None] * torch.distributed.get_world_size()
    torch.distributed.all_gather_object(gathered, obj)
    return gathered


def _batchnorms(module: nn.Module) -> list[nn.modules.batchnorm._BatchNorm]:
    return [
        m
        for m in module.modules()
        if isinstance(m, nn.modules.batchnorm._BatchNorm) and m.track_running_stats and m.running_mean is not None
    ]


@torch.no_grad()
def average_batchnorm_statistics(module: nn.Module) -> None:
    """Replace every BatchNorm's running mean and variance by their mean over the ranks (one all-reduce).

    Each rank's statistics after a training forward are ``(1 - m) * previous + m * statistics of its shard``
    from the same ``previous`` (DDP broadcast it); their mean is the update with the shard statistics averaged
    over the whole global batch. ``num_batches_tracked`` is the same on every rank and is left as it is."""
    if not _distributed() or torch.distributed.get_world_size() < 2:
        return
    norms = _batchnorms(module)
    if not norms:
        return
    tensors = [t for m in norms for t in (m.running_mean, m.running_var)]
    flat = torch.cat([t.reshape(-1).float() for t in tensors])
    torch.distributed.all_reduce(flat, op=torch.distributed.ReduceOp.SUM)
    flat /= torch.distributed.get_world_size()
    offset = 0
    for t in tensors:
        n = t.numel()
        t.copy_(flat[offset : offset + n].view_as(t))
        offset += n


def rank_random_generators() -> bool:
    """Give this rank its own torch random stream (CPU and accelerators) if it is rank > 0 of a distributed run.

    Every rank starts from lerobot-train's ``--seed`` (or the same restored RNG state on ``--resume``), so their
    streams are equal; ranks > 0 reseed from a number drawn from that stream and their rank. Rank 0 keeps its
    stream, so a single-process run is unchanged. Returns whether it reseeded."""
    rank = process_rank() if _distributed() else 0
    if rank == 0:
        return False
    base = int(torch.randint(0, 2**62, ()).item())
    torch.manual_seed(int(np.random.SeedSequence([base, rank]).generate_state(1, dtype=np.uint64)[0] >> 1))
    return True
