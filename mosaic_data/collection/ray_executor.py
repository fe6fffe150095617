"""``mosaic-data collect --executor ray``: the shards of :mod:`.collect` as Ray tasks.

A shard is the same unit as on local worker processes: the same episode slots, seeds and frames, written into a
temporary folder and renamed into place once LeRobot has finalized it. So the datasets are the local executor's,
episode for episode, whatever the number of Ray workers, and a shard whose worker died (``kill -9``, the
out-of-memory killer, a lost node) is simply run again by Ray: the dead worker's temporary folder is never merged.
Workers on other nodes write into the staging folder beside the dataset, so ``--output-dir`` must be on a
filesystem every node mounts at the same path; the run checks that before any work and says so if not.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from mosaic_data.collection import CollectionError
from mosaic_data.collection.plan import ShardSpec
from mosaic_data.collection.worker import EnvironmentCache, ShardResult, collect_shard
from mosaic_data.ray_cluster import (
    MAX_RETRIES,
    WorkerResources,
    check_shared_folder,
    cluster_cpus,
    stop_tasks,
    task_error_line,
    worker_env,
)

COLLECT_WORKER = WorkerResources(num_cpus=1, memory_gb=2.0)
"""What Ray reserves per collection worker: above a worker's peak resident memory (imports and one scene; the
measured figure is in the README's "Speed and memory per frame")."""
POLL_S = 0.5

_environments: EnvironmentCache | None = None
"""The Ray worker process's scene, kept between its tasks (building one costs seconds) as a local worker keeps it."""


def collect_shard_task(spec: ShardSpec, events) -> ShardResult:
    """One shard on a Ray worker; each finished episode is reported on ``events`` for the driver's progress bar."""
    global _environments
    from mosaic_data.collection.quiet import quiet_dataset_writing

    quiet_dataset_writing()
    if _environments is None:
        _environments = EnvironmentCache()
    return collect_shard(spec, _environments, on_episode=lambda record: _report(events, spec.name, record))


def _report(events, shard_name: str, record: dict) -> None:
    """Best effort: the progress queue may be gone with a lost node; the shard's result carries its episodes anyway."""
    try:
        events.put_nowait((shard_name, record))
    except Exception:
        pass


def run_shards_on_ray(
    ray: Any,
    pending: list[ShardSpec],
    workers: int | None,
    on_episode: Callable[[dict], None],
    on_shard: Callable[[ShardResult], None],
) -> int:
    """Run ``pending`` on the connected Ray (:func:`mosaic_data.ray_cluster.ray_session`), at most ``workers`` at a
    time (None: one per cluster CPU); returns the workers used.

    Progress counts an episode once, even when a retried shard reports it again."""
    from ray.util.queue import Empty, Queue

    for staging in {spec.staging_dir for spec in pending}:
        check_shared_folder(ray, staging, COLLECT_WORKER)
    limit = workers or cluster_cpus(ray) // max(1, int(COLLECT_WORKER.num_cpus))
    limit = max(1, min(limit, len(pending)))
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    # The progress queue lives on the driver's node, so losing another node does not lose it.
    here = NodeAffinitySchedulingStrategy(ray.get_runtime_context().get_node_id(), soft=True)
    events = Queue(actor_options={"num_cpus": 0, "scheduling_strategy": here})
    task = ray.remote(collect_shard_task).options(
        max_retries=MAX_RETRIES, retry_exceptions=False,
        runtime_env=worker_env(ray, COLLECT_WORKER.num_cpus), **COLLECT_WORKER.options(),
    )
    queued = list(pending)
    running: dict = {}  # object ref -> shard
    seen: set[tuple[str, str, int]] = set()  # (repo, shard, slot) already counted on the progress bar

    def count(shard_name: str, record: dict) -> None:
        key = (f"{record['task']}_{record['robot']}", shard_name, record["slot"])
        if key not in seen:
            seen.add(key)
            on_episode(record)

    def report_episodes() -> None:
        while True:
            try:
                shard_name, record = events.get_nowait()
            except Empty:
                return
            except ray.exceptions.RayActorError:  # the queue is gone with its node: shards still report their episodes
                return
            count(shard_name, record)

    try:
        while queued or running:
            while queued and len(running) < limit:
                spec = queued.pop(0)
                running[task.remote(spec, events)] = spec
            done, _ = ray.wait(list(running), num_returns=1, timeout=POLL_S)
            report_episodes()
            for ref in done:
                spec = running.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as error:
                    what = f"shard {spec.name} of {spec.settings.task}/{spec.settings.robot}"
                    raise CollectionError(
                        f"{task_error_line(error, what)}; finished shards are kept: run the same command again to resume"
                    ) from None
                for record in result.episodes:  # episodes whose events were lost with a dead worker or the queue
                    count(spec.name, record)
                on_shard(result)
        report_episodes()
    except BaseException:
        stop_tasks(ray, list(running))
        raise
    return limit


