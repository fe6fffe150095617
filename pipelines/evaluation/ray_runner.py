"""``mosaic-eval --executor ray``: evaluation episodes as Ray tasks.

An episode is the same unit as on the local worker processes (:mod:`.runner`): its result depends only on its seeds,
and every Ray worker runs torch and the renderer on one thread, as a local worker does, so the results equal the
local executor's whatever the number of Ray workers. A worker process keeps its agents and environments between
episodes of one evaluation. An episode whose worker died (``kill -9``, the out-of-memory killer, a lost node) is run
again by Ray; one that fails by itself stops the evaluation, as locally. Checkpoints and ``--demo-dataset`` are
read by the workers, so on a cluster they must be on a filesystem every node mounts at the same path.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

from mosaic_data.ray_cluster import MAX_RETRIES, WorkerResources, cluster_cpus, ray_session, stop_tasks, task_error_line, worker_env

from .agents import AgentSpec
from .demo_sources import DemoSourceSpec
from .options import POLL_S, WorkerDied
from .rollouts import EpisodeResult, EpisodeSpec, RolloutWorker

EVAL_WORKER = WorkerResources(num_cpus=1, memory_gb=2.0)
"""One thread of torch and of the software renderer. Memory measured: 2.0 GB peak for one process evaluating an
untrained MOSAIC at 100x180 (imports, policy, the agent's scene and the demonstrator's)."""

_worker: tuple[str, RolloutWorker] | None = None
"""The Ray worker process's rollout worker and the evaluation it belongs to (agents and scenes are kept)."""


def run_episode_task(run_id: str, agent_specs: list[AgentSpec], demo_spec: DemoSourceSpec, max_steps: int | None, spec: EpisodeSpec) -> EpisodeResult:
    """One episode on a Ray worker."""
    global _worker
    import torch

    torch.set_num_threads(1)
    if _worker is None or _worker[0] != run_id:
        if _worker is not None:
            _worker[1].close()
        _worker = (run_id, RolloutWorker(agent_specs, demo_spec, max_steps))
    result = _worker[1].run(spec)
    return result


def results_on_ray(
    specs: list[EpisodeSpec], agent_specs: list[AgentSpec], demo_spec: DemoSourceSpec, workers: int | None,
    max_steps: int | None, address: str | None, on_workers: Callable[[int], None] | None = None,
) -> Iterator[EpisodeResult]:
    """Yield the results of ``specs`` as Ray finishes them, at most ``workers`` episodes at a time (None: one per
    cluster CPU)."""
    with ray_session(address) as ray:
        limit = max(1, min(workers or cluster_cpus(ray), len(specs)))
        if on_workers is not None:
            on_workers(limit)
        task = ray.remote(run_episode_task).options(
            max_retries=MAX_RETRIES, retry_exceptions=False,
            runtime_env=worker_env(ray, EVAL_WORKER.num_cpus), **EVAL_WORKER.options(),
        )
        run_id = uuid.uuid4().hex
        shared = [ray.put([_absolute(agent) for agent in agent_specs]), ray.put(_absolute_demo(demo_spec))]
        queued = list(specs)
        running: dict = {}
        try:
            while queued or running:
                while queued and len(running) < limit:
                    spec = queued.pop(0)
                    running[task.remote(run_id, *shared, max_steps, spec)] = spec
                done, _ = ray.wait(list(running), num_returns=1, timeout=POLL_S)
                for ref in done:
                    spec = running.pop(ref)
                    try:
                        yield ray.get(ref)
                    except ray.exceptions.RayTaskError as error:
                        cause = getattr(error, "cause", None)
                        if isinstance(cause, Exception) and not isinstance(cause, ray.exceptions.RayError):
                            raise cause from None  # the episode's own error, as the local executor raises it
                        raise WorkerDied(task_error_line(error, _what(spec))) from None
                    except ray.exceptions.RayError as error:
                        raise WorkerDied(task_error_line(error, _what(spec))) from None
        finally:
            stop_tasks(ray, list(running))


def _absolute(agent: AgentSpec) -> AgentSpec:
    """Workers do not run in this folder (nor on this node): hand them absolute checkpoint paths."""
    return agent if agent.path is None else replace(agent, path=str(Path(agent.path).expanduser().absolute()))


def _absolute_demo(demo_spec: DemoSourceSpec) -> DemoSourceSpec:
    if demo_spec.dataset is None:
        return demo_spec
    return replace(demo_spec, dataset=str(Path(demo_spec.dataset).expanduser().absolute()))


def _what(spec: EpisodeSpec) -> str:
    return f"{spec.task} variation {spec.variation} episode {spec.episode}"
