"""``mosaic-data collect``: expert episodes of every variation, for both robots, into LeRobot datasets.

Flow: check every input before anything is written; for each (task, robot) dataset take a lock on its
staging folder and list the shards not yet committed (a resumed run skips the others); let worker processes
write the shards; merge each dataset's shards with LeRobot's aggregation as soon as they are all there; with
``--task all`` merge the per-task datasets into ``mosaic/all_<robot>``.
"""

from __future__ import annotations

import fcntl
import importlib
import multiprocessing
import os
import queue
import shutil
import threading
import time
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mosaic_data.action_noise import ActionNoise
from mosaic_data.atomic_files import write_json_atomically
from mosaic_data.cli_args import ray_address_problem
from mosaic_data.collection import CollectionError
from mosaic_data.collection.merge import aggregate_into, check_replaceable, merge_datasets, remove_stale_work
from mosaic_data.collection.metadata import build_sidecar, read_sidecar
from mosaic_data.collection.plan import MAX_EPISODES, CollectionSettings, DatasetJob, ShardSpec
from mosaic_data.collection.schema import (
    check_output_dir,
    dataset_root,
    is_lerobot_dataset,
    merged_repo_id_for,
    schema_mismatch,
)
from mosaic_data.collection.worker import TEMPORARY_MARK, ShardResult, read_shard_records, worker_main
from mosaic_data.process_env import scoped_environment, stop_processes
from mosaic_data.ray_cluster import EXECUTORS, ray_session
from mosaic_data.tasks.spec import IMAGE_HEIGHT, IMAGE_WIDTH

ALL_TASKS = "all"
PLAN_NAME = "plan.json"
LOCK_NAME = "lock"
WORKER_THREAD_VARIABLES = ("LP_NUM_THREADS", "OMP_NUM_THREADS")
"""Threads of llvmpipe (the renderer) and OpenMP per worker: the cores divided among the workers, so that one
worker renders with every core and N workers do not oversubscribe them."""


@dataclass
class CollectRequest:
    """What the user asked for; see ``mosaic-data collect --help``."""

    task: str
    robots: list[str]
    variations: list[int] | None = None
    episodes: int = 100
    workers: int | None = None
    """Shards collected at once; None: one per core here (local) or per CPU of the Ray cluster."""
    output_dir: Path | None = None
    seed: int = 0
    overwrite: bool = False
    image_height: int = IMAGE_HEIGHT
    image_width: int = IMAGE_WIDTH
    executor: str = "local"
    """'local' (worker processes on this machine) or 'ray' (:mod:`.ray_executor`): the same datasets either way."""
    ray_address: str | None = None
    """The Ray cluster to use with ``executor='ray'``; None starts a local Ray."""
    action_noise: ActionNoise | None = None
    """DART-style noise on the executed actions (``--action-noise``; :mod:`mosaic_data.action_noise`); None: none."""


@dataclass
class DatasetOutcome:
    repo_id: str
    root: Path
    status: str
    episodes: int = 0
    frames: int = 0
    retries: int = 0


@dataclass
class CollectReport:
    datasets: list[DatasetOutcome] = field(default_factory=list)
    episodes_collected: int = 0
    frames_collected: int = 0
    wall_s: float = 0.0
    rollout_s: float = 0.0
    write_s: float = 0.0
    worker_peak_rss_mb: float = 0.0
    workers_used: int = 0
    """Worker processes that actually ran: ``--workers`` at most, one per pending shard at most."""


# ---------------------------------------------------------------------- input checks
def plan_jobs(request: CollectRequest) -> list[DatasetJob]:
    """The datasets to produce, after checking every input (raises ValueError naming the fix).

    Plain data and the file system only: ``mosaic-data collect`` calls it before it loads LeRobot, the simulator
    or Ray, so a typo costs a fraction of a second, not the seconds of those imports.
    """
    from mosaic_data.tasks import TASK_NAMES, TASK_SPECS, get_task_spec, unknown_task_error, validate_robot  # the table only

    if request.task == ALL_TASKS:
        if request.variations is not None:
            raise ValueError("--variations cannot be combined with --task all: variation indices differ per task")
        tasks = list(TASK_NAMES)
    elif request.task in TASK_SPECS:
        tasks = [request.task]
    else:
        raise unknown_task_error(request.task, "--task", extra_choices=(ALL_TASKS,))
    for robot in request.robots:
        validate_robot(robot)
    if not 1 <= request.episodes <= MAX_EPISODES:
        raise ValueError(f"--episodes must be between 1 and {MAX_EPISODES}, got {request.episodes}")
    if request.executor not in EXECUTORS:
        raise ValueError(f"--executor must be one of {', '.join(EXECUTORS)}, got {request.executor!r}")
    if (problem := ray_address_problem(request.executor, request.ray_address)) is not None:
        raise ValueError(problem)
    if request.workers is not None and request.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {request.workers}")
    if request.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {request.seed}")
    if request.variations is not None:
        if not request.variations:
            raise ValueError("--variations is empty: give indices such as 0,3,5")
        if len(set(request.variations)) != len(request.variations):
            raise ValueError(f"--variations lists an index twice: {','.join(map(str, request.variations))}")
    check_output_dir(request.output_dir)
    jobs = []
    for task in tasks:
        spec = get_task_spec(task)
        variations = request.variations if request.variations is not None else [v.index for v in spec.variations]
        for variation in variations:
            spec.validate_variation(variation)
        for robot in request.robots:
            settings = CollectionSettings(
                task=task,
                robot=robot,
                variations=tuple(sorted(variations)),
                episodes_per_variation=request.episodes,
                base_seed=request.seed,
                image_height=request.image_height,
                image_width=request.image_width,
                action_noise=request.action_noise,
            )
            jobs.append(DatasetJob(settings, request.output_dir))
    return jobs


def source_of(job: DatasetJob) -> dict[str, Any]:
    """How a dataset was made, as recorded in its sidecar; equal sources mean the dataset is already complete."""
    return {"repo_id": job.repo_id, "task": job.settings.task, "robot": job.settings.robot, "settings": job.settings.to_json()}


def _existing_dataset_state(root: Path, expected_sources: list[dict], request: CollectRequest, resumable: Path | None = None) -> str:
    """'absent', 'complete' (same sources), or raise unless ``--overwrite``; returns 'replace' with it.

    ``resumable``: the staging folder of an unfinished run of these very settings (an interrupted
    ``--overwrite``), which the error then says that ``--overwrite`` resumes.
    """
    if not root.exists() and not root.is_symlink():
        return "absent"
    if request.overwrite:
        check_replaceable(root, flag="--output-dir")
        return "replace"
    if not is_lerobot_dataset(root):
        raise ValueError(f"{root} exists but is not a LeRobot dataset: move it away, choose another --output-dir, or add --overwrite")
    mismatch = schema_mismatch(root, request.image_height, request.image_width)
    if mismatch is not None:
        raise ValueError(f"{root} holds a dataset of another schema ({mismatch}): choose another --output-dir, or add --overwrite to replace it")
    sidecar = read_sidecar(root)
    if sidecar is None:
        raise ValueError(f"{root} holds a LeRobot dataset that `mosaic-data collect` did not make (no meta/mosaic.json): choose another --output-dir, or add --overwrite")
    if sidecar.get("sources") != expected_sources:
        raise ValueError(
            f"{root} was collected with other settings ({_settings_difference(sidecar.get('sources'), expected_sources)}): "
            "rerun with the same options, or add --overwrite to replace it"
            + (f" (this resumes the unfinished --overwrite run in {resumable})" if resumable is not None else "")
        )
    return "complete"


def _settings_difference(found: list[dict] | None, expected: list[dict]) -> str:
    if not found or len(found) != len(expected):
        return f"{len(found or [])} sources instead of {len(expected)}"
    for old, new in zip(found, expected):
        old_settings, new_settings = old.get("settings", {}), new.get("settings", {})
        for key in list(new_settings) + [key for key in old_settings if key not in new_settings]:
            if old_settings.get(key) != new_settings.get(key):
                return f"{old.get('repo_id')}: {key} {_setting_text(key, old_settings.get(key))} instead of {_setting_text(key, new_settings.get(key))}"
    return "different sources"


def _setting_text(key: str, value: Any) -> str:
    """A setting as the difference names it: the noise as its two stds (or 'none'), not its whole record."""
    if key == "action_noise":
        if not isinstance(value, dict):
            return "none"
        return f"{value.get('position_std_m')} m,{value.get('rotation_std_rad')} rad"
    return str(value)


# ---------------------------------------------------------------------- collection
def collect(request: CollectRequest, show_progress: bool = True) -> CollectReport:
    """Collect, resume or leave alone the requested datasets (see the module docstring)."""
    from tqdm import tqdm

    started = time.perf_counter()
    if request.executor == "ray" and request.output_dir is not None:  # Ray workers run elsewhere: no relative paths
        request.output_dir = Path(request.output_dir).expanduser().absolute()
    jobs = plan_jobs(request)
    for root in [job.root for job in jobs] + [dataset_root(request.output_dir, merged_repo_id_for(r)) for r in request.robots]:
        remove_stale_work(root)  # a killed merge's leftovers (of processes that are gone): an old dataset comes back
    staged_same = {job.repo_id: _staged_same_settings(job) for job in jobs}  # an unfinished run of these settings
    states = {
        job.repo_id: _existing_dataset_state(
            job.root, [source_of(job)], request, resumable=job.staging_dir if staged_same[job.repo_id] else None
        )
        for job in jobs
    }
    for job in jobs:
        if states[job.repo_id] != "complete" and not request.overwrite:
            _check_staging(job)
    discard = {job.repo_id for job in jobs if request.overwrite and not staged_same[job.repo_id]}
    merged, merged_complete = [], []
    if request.task == ALL_TASKS:
        for robot in request.robots:
            sources = [source_of(job) for job in jobs if job.settings.robot == robot]
            root = dataset_root(request.output_dir, merged_repo_id_for(robot))
            if _existing_dataset_state(root, sources, request) != "complete":
                merged.append((robot, root))
            else:
                merged_complete.append((robot, root))
    # Everything has been checked: from here on we write.
    report = CollectReport()
    to_collect = [job for job in jobs if states[job.repo_id] != "complete"]
    report.datasets = [
        _outcome(job, "complete, left alone") for job in jobs if states[job.repo_id] == "complete"
    ]
    with ExitStack() as stack:
        # Connect to Ray before anything is staged: an unreachable cluster leaves no trace.
        ray = stack.enter_context(ray_session(request.ray_address)) if request.executor == "ray" and to_collect else None
        pending_by_job = stack.enter_context(_locked_staging(to_collect, discard))
        pending = [spec for job in to_collect for spec in pending_by_job[job.repo_id]]
        total = sum(job.total_episodes for job in to_collect)
        already = total - sum(spec.num_episodes for spec in pending)
        remaining_shards = {job.repo_id: len(pending_by_job[job.repo_id]) for job in to_collect}
        jobs_by_repo = {job.repo_id: job for job in to_collect}
        with tqdm(total=total, initial=already, desc="collect", unit="episode", disable=not show_progress or total == 0, dynamic_ncols=True) as progress:
            def on_episode(record: dict) -> None:
                progress.update(1)
                progress.set_postfix_str(f"{record['task']}/{record['robot']} v{record['variation']}", refresh=False)

            def on_shard(result: ShardResult) -> None:
                report.episodes_collected += len(result.episodes)
                report.frames_collected += result.frames
                report.rollout_s += result.rollout_s
                report.write_s += result.write_s
                report.worker_peak_rss_mb = max(report.worker_peak_rss_mb, result.peak_rss_mb)
                remaining_shards[result.repo_id] -= 1
                if remaining_shards[result.repo_id] == 0:
                    _finish_job(jobs_by_repo[result.repo_id])

            for job in to_collect:  # resumed runs may have every shard already
                if remaining_shards[job.repo_id] == 0:
                    _finish_job(job)
            if pending:
                # LeRobot's aggregation (torch, datasets) takes seconds to import: do it while the workers
                # collect, not after the last shard.
                threading.Thread(target=importlib.import_module, args=("lerobot.datasets.aggregate",), daemon=True).start()
                if request.executor == "ray":
                    from mosaic_data.collection.ray_executor import run_shards_on_ray

                    report.workers_used = run_shards_on_ray(ray, pending, request.workers, on_episode, on_shard)
                else:
                    report.workers_used = min(request.workers or os.cpu_count() or 1, len(pending))
                    _run_workers(pending, report.workers_used, on_episode, on_shard)
    report.datasets += [_outcome(job, "collected") for job in to_collect]
    for robot, root in merged_complete:
        report.datasets.append(_outcome_of(merged_repo_id_for(robot), root, "complete, left alone"))
    for robot, root in merged:
        sources = [job.root for job in jobs if job.settings.robot == robot]
        merge_datasets(sources, merged_repo_id_for(robot), root)
        report.datasets.append(_outcome_of(merged_repo_id_for(robot), root, "merged"))
    report.wall_s = time.perf_counter() - started
    return report


def _staged_plan(job: DatasetJob) -> dict | None:
    """The settings of the unfinished run in the job's staging folder, or None (no run, or an unreadable plan
    written by a run that crashed before it started a shard)."""
    import json

    try:
        return json.loads((job.staging_dir / PLAN_NAME).read_text())
    except (OSError, ValueError):
        return None


def _staged_same_settings(job: DatasetJob) -> bool:
    """Whether an unfinished run of exactly these settings waits in staging: rerunning resumes it, even with
    ``--overwrite`` (which must not throw away the finished shards of the very run it repeats)."""
    return _staged_plan(job) == source_of(job)


def _check_staging(job: DatasetJob) -> None:
    staged = _staged_plan(job)
    if staged is None:
        return  # nothing staged, or an unreadable plan: it is replaced
    if staged != source_of(job):
        raise ValueError(
            f"an unfinished collection of {job.repo_id} with other settings is in {job.staging_dir} "
            f"({_settings_difference([staged], [source_of(job)])}): rerun with the same options to finish it, "
            "or add --overwrite to start over"
        )


@contextmanager
def _locked_staging(jobs: list[DatasetJob], discard: set[str]):
    """Lock each job's staging folder, clean what a killed run left, and yield the shards still to do.

    The staged runs of the repo ids in ``discard`` (``--overwrite`` of a run with other settings) start over.
    """
    handles = []
    try:
        pending: dict[str, list[ShardSpec]] = {}
        for job in jobs:
            staging = job.staging_dir
            if job.repo_id in discard and staging.exists():
                _lock(staging, handles, job)
                shutil.rmtree(staging)
                handles.pop().close()
            staging.mkdir(parents=True, exist_ok=True)
            _lock(staging, handles, job)
            write_json_atomically(staging / PLAN_NAME, source_of(job))
            shards_dir = staging / "shards"
            shards_dir.mkdir(exist_ok=True)
            for leftover in shards_dir.iterdir():  # shards in flight when a previous run was killed
                if TEMPORARY_MARK in leftover.name:
                    shutil.rmtree(leftover, ignore_errors=True)
            pending[job.repo_id] = [spec for spec in job.shards() if not spec.is_done]
        yield pending
    finally:
        for handle in handles:
            handle.close()


def _lock(staging: Path, handles: list, job: DatasetJob) -> None:
    handle = open(staging / LOCK_NAME, "a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.close()
        raise ValueError(f"another `mosaic-data collect` is writing {job.repo_id} (lock {staging / LOCK_NAME}): wait for it to finish") from None
    handles.append(handle)


def _finish_job(job: DatasetJob) -> None:
    """Merge a job's committed shards, in slot order, into its dataset and drop the staging folder."""
    shards = job.shards()
    records = []
    for spec in shards:
        records.extend(read_shard_records(spec.root))
    episodes = [{"episode_index": index, **record} for index, record in enumerate(records)]
    sidecar = build_sidecar(job.repo_id, [source_of(job)], episodes)
    kept = f"the finished shards stay in {job.staging_dir}"
    aggregate_into([(job.repo_id, spec.root) for spec in shards], job.repo_id, job.root, sidecar, kept=kept)
    shutil.rmtree(job.staging_dir, ignore_errors=True)


def _run_workers(pending: list[ShardSpec], workers: int, on_episode, on_shard) -> None:
    """Run ``pending`` shards on ``workers`` spawned processes; stop them all on any error or Ctrl-C."""
    context = multiprocessing.get_context("spawn")  # MuJoCo's GL contexts do not survive fork
    shard_queue, event_queue = context.Queue(), context.Queue()
    for spec in pending:
        shard_queue.put(spec)
    processes = [
        context.Process(target=worker_main, args=(index, os.getpid(), shard_queue, event_queue), name=f"mosaic-collect-{index}")
        for index in range(min(workers, len(pending)))
    ]
    for _ in processes:
        shard_queue.put(None)
    try:
        with _worker_environment(len(processes)):
            for process in processes:
                process.start()
        remaining = len(pending)
        while remaining:
            try:
                kind, worker, payload = event_queue.get(timeout=1.0)
            except queue.Empty:
                crashed = [p for p in processes if p.exitcode not in (None, 0)]
                if crashed:
                    raise CollectionError(
                        f"collection worker {crashed[0].name} died (exit code {crashed[0].exitcode}, e.g. out of memory): "
                        "run the same command again to resume, with fewer --workers if memory is short"
                    ) from None
                continue
            if kind == "episode":
                on_episode(payload)
            elif kind == "shard":
                remaining -= 1
                on_shard(payload)
            elif kind == "error":
                raise CollectionError(payload)
    finally:
        stop_processes(processes)
        shard_queue.cancel_join_thread()
        event_queue.cancel_join_thread()


def _worker_environment(workers: int):
    """Environment variables the spawned workers inherit (the parent's own are restored afterwards)."""
    threads = str(max(1, (os.cpu_count() or 1) // max(1, workers)))
    return scoped_environment(
        default={name: threads for name in WORKER_THREAD_VARIABLES}
        | {"MUJOCO_GL": "egl"}
    )


def _outcome(job: DatasetJob, status: str) -> DatasetOutcome:
    return _outcome_of(job.repo_id, job.root, status)


def _outcome_of(repo_id: str, root: Path, status: str) -> DatasetOutcome:
    sidecar = read_sidecar(root) or {"episodes": []}
    episodes = sidecar["episodes"]
    return DatasetOutcome(
        repo_id=repo_id,
        root=root,
        status=status,
        episodes=len(episodes),
        frames=sum(record["length"] for record in episodes),
        retries=sum(record["attempts"] - 1 for record in episodes),
    )
