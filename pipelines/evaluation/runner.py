"""Run evaluation episodes on worker processes (rendering and the policy's CPU time are the cost).

Each worker is a spawned process (MuJoCo's GL contexts do not survive a fork) holding its own agents,
environments and demo sources; episodes are handed out one at a time and come back in any order, then are
sorted, so the result list is the same whatever the worker count. Every worker runs torch and the software
renderer on one thread: parallelism comes from the processes, and a fixed thread count keeps the floating-point
results identical between a run with 1 worker and one with 4.

The workers are plain processes watched by the parent (not a ``multiprocessing.Pool``, which silently replaces
a worker killed by the out-of-memory killer and then waits forever for the episode it held): a worker that
dies stops the evaluation with :class:`WorkerDied`, and the episodes that finished before stay with the caller
(``on_result`` has seen each). A worker dies with its parent, so a killed ``mosaic-eval`` leaves no orphans.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import traceback
from collections.abc import Callable, Iterator
from typing import Any

from mosaic_data.process_env import scoped_environment, stop_processes

from .agents import AgentSpec
from .demo_sources import DemoSourceSpec
from .options import POLL_S, WorkerDied
from .rollouts import EpisodeResult, EpisodeSpec, RolloutWorker

THREAD_VARIABLES = ("LP_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def run_episodes(
    specs: list[EpisodeSpec],
    agent_specs: list[AgentSpec],
    demo_spec: DemoSourceSpec,
    workers: int | None = 1,
    on_result: Callable[[EpisodeResult], None] | None = None,
    max_steps: int | None = None,
    executor: str = "local",
    ray_address: str | None = None,
    on_workers: Callable[[int], None] | None = None,
) -> list[EpisodeResult]:
    """Run every episode of ``specs``; ``on_result`` sees each result as it arrives (progress, recording, and
    the finished episodes a caller keeps if the evaluation stops early).

    ``max_steps`` caps every task's horizon (smoke tests); None evaluates up to the horizon. ``executor='ray'``
    runs the episodes as Ray tasks (:mod:`.ray_runner`, on the cluster at ``ray_address`` or a local Ray), with the
    same results; ``workers`` None means one per core (local) or per cluster CPU (Ray). ``on_workers`` is told how
    many workers run (for the timing report)."""
    if executor == "ray":
        from .ray_runner import results_on_ray

        episodes = results_on_ray(specs, agent_specs, demo_spec, workers, max_steps, ray_address, on_workers)
    else:
        workers = min(workers or os.cpu_count() or 1, max(1, len(specs)))
        if on_workers is not None:
            on_workers(workers)
        episodes = _results(specs, agent_specs, demo_spec, workers, max_steps)
    results = []
    for result in episodes:
        if on_result is not None:
            on_result(result)
        result.recording = None  # logged by on_result; do not keep frames of the whole evaluation in memory
        results.append(result)
    return in_plan_order(results, specs)


def in_plan_order(results: list[EpisodeResult], specs: list[EpisodeSpec]) -> list[EpisodeResult]:
    """``results`` sorted as their episodes are in ``specs``: the same list whatever the worker count."""
    order = {(s.agent_index, s.task, s.variation, s.episode): position for position, s in enumerate(specs)}
    return sorted(results, key=lambda r: order[(r.agent_index, r.task, r.variation, r.episode)])


def _results(
    specs: list[EpisodeSpec], agent_specs: list[AgentSpec], demo_spec: DemoSourceSpec, workers: int, max_steps: int | None
) -> Iterator[EpisodeResult]:
    if workers <= 1 or len(specs) <= 1:
        yield from _in_process(specs, agent_specs, demo_spec, max_steps)
    else:
        yield from _on_workers(specs, agent_specs, demo_spec, min(workers, len(specs)), max_steps)


def _in_process(
    specs: list[EpisodeSpec], agent_specs: list[AgentSpec], demo_spec: DemoSourceSpec, max_steps: int | None
) -> Iterator[EpisodeResult]:
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


def _on_workers(
    specs: list[EpisodeSpec], agent_specs: list[AgentSpec], demo_spec: DemoSourceSpec, workers: int, max_steps: int | None
) -> Iterator[EpisodeResult]:
    """Episodes from a shared queue; each worker reports on its own pipe, so a worker killed in the middle of a
    message leaves the parent an end-of-file on that pipe, never a read that waits forever."""
    context = multiprocessing.get_context("spawn")
    tasks = context.Queue()
    for spec in specs:
        tasks.put(spec)
    for _ in range(workers):
        tasks.put(None)
    processes, readers = [], []
    try:
        with _single_threaded():
            for index in range(workers):
                reader, writer = context.Pipe(duplex=False)
                process = context.Process(
                    target=_worker_main, args=(os.getpid(), agent_specs, demo_spec, max_steps, tasks, writer),
                    name=f"mosaic-eval-{index}",
                )
                process.start()
                writer.close()  # the worker holds the only write end: its death reads as end-of-file here
                processes.append(process)
                readers.append(reader)
        yield from _collect(processes, readers, len(specs))
    finally:
        stop_processes(processes)
        for reader in readers:
            reader.close()
        tasks.cancel_join_thread()
        # The queue's feeder thread ends here, so no "leaked semaphore" warning follows the command's last line (after
        # a worker is killed, say): a feeder left running holds the queue's semaphore until the interpreter shuts
        # down, and freeing it from that thread can unlink it without telling the resource tracker.
        tasks.close()


def _collect(processes: list, readers: list, total: int) -> Iterator[EpisodeResult]:
    """Yield ``total`` results as the workers send them; raise as soon as a worker fails or dies."""
    from multiprocessing.connection import wait

    running: dict[int, EpisodeSpec] = {}  # worker index -> the episode it said it started
    finished: set[int] = set()  # workers that said "done": the queue had nothing left for them
    open_readers = dict(enumerate(readers))
    remaining = total
    while remaining:
        ready = wait(list(open_readers.values()), timeout=POLL_S)
        for index, reader in list(open_readers.items()):
            if reader not in ready:
                continue
            try:
                kind, payload = reader.recv()
            except (EOFError, OSError):  # the worker is gone (a message cut short reads as EOF too)
                del open_readers[index]
                if index in finished or not remaining:
                    continue
                # it ended without saying "done": killed (before, during or between episodes) or crashed; the exit
                # code names how, once the process is reaped (slow on a loaded machine)
                processes[index].join(timeout=60)
                raise WorkerDied(_death(processes[index], running.get(index))) from None
            if kind == "done":
                finished.add(index)
            elif kind == "start":
                running[index] = payload
            elif kind == "result":
                running.pop(index, None)
                remaining -= 1
                yield payload
            elif kind == "error":
                raise _worker_error(payload)
        if remaining and not open_readers:
            raise WorkerDied(f"every evaluation worker ended with {remaining} episode(s) unreported")


def _death(process, spec: EpisodeSpec | None) -> str:
    during = "" if spec is None else f" during {spec.task} variation {spec.variation} episode {spec.episode}"
    return f"evaluation worker {process.name} died ({_how(process.exitcode)}){during}"


def _how(exitcode: int | None) -> str:
    if exitcode is None:
        return "it closed its pipe but did not exit"
    if exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        hint = ", e.g. by the out-of-memory killer" if -exitcode == signal.SIGKILL else ""
        return f"killed by {name}{hint}"
    return f"exit code {exitcode}"


def _worker_error(payload: tuple[BaseException | None, str]) -> BaseException:
    """The worker's exception, re-raised here with the worker's traceback attached (or a RuntimeError with it when
    the exception did not survive pickling)."""
    error, remote_traceback = payload
    if error is None:
        return RuntimeError(f"an evaluation worker failed:\n{remote_traceback}")
    error.add_note(f"in the evaluation worker:\n{remote_traceback}")
    return error


def _worker_main(
    parent_pid: int, agent_specs: list[AgentSpec], demo_spec: DemoSourceSpec, max_steps: int | None,
    tasks, results,
) -> None:
    """Entry point of a worker process: run episodes from ``tasks`` until a ``None``, report each on ``results``."""
    _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the process group: the parent stops the workers
    import torch

    torch.set_num_threads(1)
    worker = None
    try:
        worker = RolloutWorker(agent_specs, demo_spec, max_steps)
        while (spec := tasks.get()) is not None:
            results.send(("start", spec))
            results.send(("result", worker.run(spec)))
        results.send(("done", None))
    except Exception as error:  # report it rather than die silently; the parent decides
        results.send(("error", (_picklable(error), traceback.format_exc())))
    finally:
        if worker is not None:
            worker.close()
        results.close()


def _picklable(error: BaseException) -> BaseException | None:
    import pickle

    try:
        pickle.loads(pickle.dumps(error))
    except Exception:
        return None
    return error


def _die_with_parent(parent_pid: int) -> None:
    """The kernel kills this worker when the parent dies (Linux), so no orphan keeps rendering."""
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent_pid:  # the parent died before the line above took effect
        os._exit(1)


def _single_threaded() -> Any:
    """One thread per process for the renderer and BLAS (inherited by spawned workers), restored afterwards."""
    return scoped_environment(force={name: "1" for name in THREAD_VARIABLES}, default={"MUJOCO_GL": "egl"})
