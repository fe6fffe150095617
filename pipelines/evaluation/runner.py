"""Run evaluation episodes on worker processes (rendering and the policy's CPU time are the cost).

Each worker is a spawned process (MuJoCo's GL contexts do not survive a fork) holding its own agents,
environments and demo sources; episodes are handed out one at a time and come back in any order, then are
sorted, so the result list is the same whatever the worker count. Every worker runs torch and the software
renderer on one thread: parallelism comes from the processes, and a fixed thread count keeps the floating-point
results identical between a run with 1 worker and one with 4.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator

from mosaic_data.process_env import scoped_environment

from .agents import AgentSpec
from .demo_sources import DemoSourceSpec
from .rollouts import EpisodeResult, EpisodeSpec, RolloutWorker

THREAD_VARIABLES = ("LP_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

_worker: RolloutWorker | None = None


def _init_worker(agent_specs: list[AgentSpec], demo_spec: DemoSourceSpec, max_steps: int | None) -> None:
    global _worker
    import torch

    torch.set_num_threads(1)
    _worker = RolloutWorker(agent_specs, demo_spec, max_steps)


def _run_episode(spec: EpisodeSpec) -> EpisodeResult:
    return _worker.run(spec)


def run_episodes(
    specs: list[EpisodeSpec],
    agent_specs: list[AgentSpec],
    demo_spec: DemoSourceSpec,
    workers: int = 1,
    on_result: Callable[[EpisodeResult], None] | None = None,
    max_steps: int | None = None,
) -> list[EpisodeResult]:
    """Run every episode of ``specs``; ``on_result`` sees each result as it arrives (progress, recording).

    ``max_steps`` caps every task's horizon (smoke tests); None evaluates up to the horizon."""
    results = []
    for result in _results(specs, agent_specs, demo_spec, workers, max_steps):
        if on_result is not None:
            on_result(result)
        result.recording = None  # logged by on_result; do not keep frames of the whole evaluation in memory
        results.append(result)
    order = {(s.agent_index, s.task, s.variation, s.episode): position for position, s in enumerate(specs)}
    return sorted(results, key=lambda r: order[(r.agent_index, r.task, r.variation, r.episode)])


def _results(
    specs: list[EpisodeSpec], agent_specs: list[AgentSpec], demo_spec: DemoSourceSpec, workers: int, max_steps: int | None
) -> Iterator[EpisodeResult]:
    if workers <= 1:
        import torch

        threads = torch.get_num_threads()
        with _single_threaded():
            torch.set_num_threads(1)
            worker = RolloutWorker(agent_specs, demo_spec, max_steps)
            try:
                for spec in specs:
                    yield worker.run(spec)
            finally:
                worker.close()
                torch.set_num_threads(threads)
        return
    context = multiprocessing.get_context("spawn")
    with _single_threaded():
        pool = context.Pool(min(workers, len(specs)), initializer=_init_worker, initargs=(agent_specs, demo_spec, max_steps))
    try:
        yield from pool.imap_unordered(_run_episode, specs)
        pool.close()
    finally:
        pool.terminate()
        pool.join()


def _single_threaded():
    """One thread per process for the renderer and BLAS (inherited by spawned workers), restored afterwards."""
    return scoped_environment(force={name: "1" for name in THREAD_VARIABLES}, default={"MUJOCO_GL": "egl"})
