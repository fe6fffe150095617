"""Collection worker: runs the expert for the episode slots of one shard and writes them as a LeRobot dataset.

A shard is written into ``<name>.tmp-<pid>`` and renamed into place only once LeRobot has finalized it and
its episode records are on disk, so a shard directory without the ``.tmp`` suffix is always complete. A
worker dies with its parent (``PR_SET_PDEATHSIG``) and checks that its parent is still there before it
commits, so a killed ``collect`` leaves no orphan that could commit a shard behind a resumed run's back.
"""

from __future__ import annotations

import os
import resource
import shutil
import signal
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mosaic_data.collection.plan import ShardSpec, episode_seed
from mosaic_data.collection.quiet import quiet_dataset_writing
from mosaic_data.collection.schema import CAMERA_KEY, FPS, dataset_features, repo_id_for

SHARD_RECORD_NAME = "mosaic_shard.json"
TEMPORARY_MARK = ".tmp-"


class ExpertGaveUp(RuntimeError):
    """The expert failed every attempt of an episode slot: its task/variation needs fixing, not more seeds."""


@dataclass
class ShardResult:
    name: str
    repo_id: str
    episodes: list[dict[str, Any]]
    frames: int
    rollout_s: float
    write_s: float
    peak_rss_mb: float = field(default=0.0)


class EnvironmentCache:
    """Keeps the last scene: building one costs seconds and hundreds of megabytes that the process does not get
    back, and every task builds all its fixtures whatever the variation, so one scene per task and robot serves
    every variation (``set_variation``; a reset from a seed gives the same episode whatever ran before, tested)."""

    def __init__(self) -> None:
        self._key: tuple | None = None
        self._env = None

    def get(self, settings, variation: int):
        from mosaic_data.tasks import make_task_env

        key = (settings.task, settings.robot, settings.image_height, settings.image_width, settings.visual_face_budget)
        if key != self._key:
            self.close()
            self._env = make_task_env(
                settings.task, variation, settings.robot, image_height=settings.image_height,
                image_width=settings.image_width, visual_face_budget=settings.visual_face_budget,
            )
            self._key = key
        self._env.set_variation(variation)
        return self._env

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
        self._env, self._key = None, None


def collect_shard(spec: ShardSpec, environments: EnvironmentCache, on_episode=None, parent_pid: int | None = None) -> ShardResult:
    """Collect the shard's successful episodes and commit it; returns what was written."""
    from mosaic_data.atomic_files import give_plain_modes, write_json_atomically
    from mosaic_data.collection.episode_saving import skip_needless_image_embedding
    from mosaic_data.rollout import run_expert_episode

    skip_needless_image_embedding()

    settings = spec.settings
    repo_id = repo_id_for(settings.task, settings.robot)
    temporary = spec.root.with_name(f"{spec.name}{TEMPORARY_MARK}{os.getpid()}")
    if temporary.exists():
        shutil.rmtree(temporary)
    temporary.parent.mkdir(parents=True, exist_ok=True)
    env = environments.get(settings, spec.variation)
    dataset = create_shard_dataset(repo_id, temporary, settings.robot, settings.image_height, settings.image_width, env.horizon)
    records, frames, rollout_s, write_s = [], 0, 0.0, 0.0
    writer = _LiveEpisodeWriter(dataset, env.horizon)
    try:
        for slot in range(spec.first_slot, spec.end_slot):
            failed_seeds = []
            for attempt in range(settings.max_attempts):
                seed = episode_seed(settings.base_seed, spec.variation, slot, attempt)
                started = time.perf_counter()
                writer.seconds = 0.0
                episode = run_expert_episode(
                    env, seed, record_frames=True, record_final_frame=False, on_step=writer.add_step,
                    action_noise=settings.action_noise,
                )
                write_s += writer.seconds
                rollout_s += time.perf_counter() - started - writer.seconds
                if episode.success:
                    break
                dataset.clear_episode_buffer()  # also cancels the episode's video encoding
                failed_seeds.append(seed)
            else:
                raise ExpertGaveUp(
                    f"the {settings.task} expert failed {settings.max_attempts} attempts in a row with the "
                    f"{settings.robot} on variation {spec.variation} (episode slot {slot}, seeds {failed_seeds[0]}.."
                    f"{failed_seeds[-1]}): fix the expert or leave this variation out with --variations"
                )
            started = time.perf_counter()
            dataset.save_episode()
            write_s += time.perf_counter() - started
            frames += episode.length
            records.append({
                "task": settings.task,
                "robot": settings.robot,
                "variation": spec.variation,
                "slot": slot,
                "seed": seed,
                "attempts": len(failed_seeds) + 1,
                "failed_seeds": failed_seeds,
                "length": episode.length,
            })
            if on_episode is not None:
                on_episode(records[-1])
        started = time.perf_counter()
        dataset.finalize()
        write_s += time.perf_counter() - started
        write_json_atomically(temporary / "meta" / SHARD_RECORD_NAME, {"shard": spec.name, "episodes": records})
        give_plain_modes(temporary)  # LeRobot joins a shard's episode videos through tempfile: mode 0600
        if parent_pid is not None and os.getppid() != parent_pid:
            raise SystemExit("parent process is gone; not committing the shard")
        try:
            os.rename(temporary, spec.root)
        except OSError:
            if not spec.is_done:
                raise
            # Another run of this very shard committed first (a Ray retry of a worker thought lost): its content is
            # the same (same seeds), so keep it and drop this copy rather than fail or write the shard twice.
            shutil.rmtree(temporary, ignore_errors=True)
            records = read_shard_records(spec.root)
    except BaseException:
        shutil.rmtree(temporary, ignore_errors=True)
        raise
    peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return ShardResult(spec.name, repo_id, records, frames, rollout_s, write_s, peak_rss_mb)


def create_shard_dataset(repo_id: str, root: Path, robot: str, height: int, width: int, horizon: int):
    """An empty LeRobot dataset whose video is encoded while the frames are added (no PNG staging, half the
    writing time), with room in the encoder's queue for a whole episode.

    LeRobot's streaming encoder is built for cameras: when its queue is full for 0.1 s it drops the frame and only
    logs it. A collection on a loaded machine (the encoder thread starved for a moment) would then write a video
    shorter than its episodes. An episode adds at most ``horizon`` frames, so with a queue of ``horizon + 1`` it never
    waits and never loses a frame; the encoder gets a new queue at every episode.
    """
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset.create(
        repo_id,
        fps=FPS,
        features=dataset_features(height, width),
        root=root,
        robot_type=robot,
        use_videos=True,
        streaming_encoding=True,
        encoder_queue_maxsize=horizon + 1,
    )


class _LiveEpisodeWriter:
    """Adds each step to the LeRobot episode buffer as the expert takes it, so that the streaming video
    encoder works on the frames while the simulation goes on (instead of after the episode); a failed attempt
    is dropped with ``clear_episode_buffer``. ``seconds`` is the time spent writing, for the report."""

    def __init__(self, dataset, horizon: int) -> None:
        self.dataset = dataset
        self.horizon = horizon
        self.seconds = 0.0

    def add_step(self, episode) -> None:
        started = time.perf_counter()
        step = episode.length - 1
        self.dataset.add_frame({
            CAMERA_KEY: episode.frames[step],
            "observation.state": episode.states[step],
            "action": episode.actions[step],
            "variation": np.array([episode.variation], dtype=np.int64),
            "next.success": np.array([episode.successes[step]], dtype=bool),
            "next.done": np.array([episode.success or episode.length >= self.horizon], dtype=bool),
            "task": episode.description,
        })
        episode.frames[step] = None  # encoded: the episode need not keep it
        self.seconds += time.perf_counter() - started


def read_shard_records(shard_root: Path) -> list[dict[str, Any]]:
    import json

    return json.loads((shard_root / "meta" / SHARD_RECORD_NAME).read_text())["episodes"]


# ---------------------------------------------------------------------- worker process
def worker_main(worker_index: int, parent_pid: int, shard_queue, event_queue) -> None:
    """Entry point of a worker process: take shards from ``shard_queue`` until a ``None``, report on ``event_queue``."""
    _die_with_parent(parent_pid)
    # Ctrl-C reaches the whole process group; the parent decides what happens and stops the workers itself.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    quiet_dataset_writing()
    environments = EnvironmentCache()
    try:
        while (spec := shard_queue.get()) is not None:
            report = lambda record: event_queue.put(("episode", worker_index, record))  # noqa: E731
            try:
                result = collect_shard(spec, environments, on_episode=report, parent_pid=parent_pid)
            except ExpertGaveUp as error:
                event_queue.put(("error", worker_index, str(error)))
                return
            except Exception as error:  # report, with where it happened, rather than die silently
                detail = traceback.format_exc(limit=-3).strip().splitlines()[-1]
                event_queue.put(("error", worker_index, f"shard {spec.name} of {spec.settings.task}/{spec.settings.robot} failed: {detail or error}"))
                return
            event_queue.put(("shard", worker_index, result))
    finally:
        environments.close()


def _die_with_parent(parent_pid: int) -> None:
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(pr_set_pdeathsig, signal.SIGKILL)
    if os.getppid() != parent_pid:  # the parent died before the line above took effect
        os._exit(1)
