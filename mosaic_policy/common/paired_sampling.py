"""Pairing agent samples with demonstrator frames of the same variation, inside lerobot-train.

lerobot-train loads one dataset (the agent's). The policy owns a `PairedDemoSampler` over the demonstrator
dataset: for every agent sample of a batch it takes one demonstrator episode with the same LeRobot task
string (the variation) and a different instance, and decodes `n_frames` frames of it (first, last, one random
frame from each middle segment). Background threads decode the next batches' demonstrations while the model
trains on the current one, so the paired data path does not stall the training step; `wait_s` counts the time
the training step still had to wait for them.

"Instance": the collector seeds episode k of every variation with the same seed for both robots, so the
agent and demonstrator episodes with the same rank within their variation show the same scene instance; a
demonstrator episode of another rank is chosen whenever the variation has one.

Data fractions: when training uses a subset of the agent episodes (lerobot-train's `--dataset.episodes` or
`--dataset.eval_split`, the paper's 25/50/75% runs), the demonstrator side is restricted to the same instances
(the same ranks within each variation), so both robots see the same share of the data. A policy is not told
which episodes the run trains on, so the sampler learns them from the batches: a variation's demonstrations
come from the instances of the agent episodes it has been asked to pair so far (all of the run's, after the first
batches), never from an instance the run does not train on. `agent_episodes` fixes the set up front instead.

Several training processes (``accelerate launch``): every process has its own sampler and pairs the samples of
its own shard of the batch (the batch its policy's forward gets), with its own random stream (``process_index``,
the process's rank) and its own decode threads. A process learns the run's instances from its own batches.
"""

import threading
import time
from collections import Counter, deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch
from torch import Tensor


class DemoDatasetError(ValueError):
    """The demonstrator dataset is missing or does not match the agent dataset."""


def demo_frame_indices(length: int, n_frames: int, rng: np.random.Generator | None = None) -> list[int]:
    """First and last frame plus one frame from each of the n_frames - 2 equal middle segments.

    With `rng` the middle frames are random within their segment (training); without, the segment centres
    (inference, deterministic). Episodes shorter than n_frames repeat frames.
    """
    if length < 1:
        raise DemoDatasetError("a demonstration must have at least one frame")
    last = length - 1
    middle_frames = np.arange(1, last) if last > 1 else np.zeros(1, dtype=int)
    segments = np.array_split(middle_frames, n_frames - 2)
    middle = []
    for segment in segments:
        if len(segment) == 0:  # fewer middle frames than segments: repeat the nearest one
            segment = middle_frames[-1:]
        pick = segment[int(rng.integers(len(segment)))] if rng is not None else segment[len(segment) // 2]
        middle.append(int(pick))
    return [0, *middle, last]


def _episode_ranks(episode_tasks: list[str]) -> list[int]:
    """Rank of every episode among the episodes of its variation, in episode order."""
    seen: Counter = Counter()
    ranks = []
    for task in episode_tasks:
        ranks.append(seen[task])
        seen[task] += 1
    return ranks


def _episode_tasks(meta) -> list[str]:
    return [tasks[0] if len(tasks) else "" for tasks in meta.episodes["tasks"]]


class PairedDemoSampler:
    """Demonstrator frames for batches of agent samples; see the module docstring."""

    def __init__(
        self,
        repo_id: str,
        root: str | Path | None,
        image_key: str,
        n_frames: int,
        agent_meta=None,
        agent_episodes: list[int] | None = None,
        threads: int = 2,
        prefetch_batches: int = 2,
        seed: int = 0,
        process_index: int = 0,
    ):
        from lerobot.datasets import LeRobotDatasetMetadata

        where = f"root {root}" if root else "LeRobot's cache ($HF_LEROBOT_HOME)"
        if root is not None and not (Path(root) / "meta" / "info.json").exists():
            raise DemoDatasetError(
                f"demonstrator dataset {repo_id!r} not found at {root}: collect it (mosaic-data collect "
                "--robot sawyer ...) or point --policy.demo_root at its folder."
            )
        try:
            self.meta = LeRobotDatasetMetadata(repo_id, root=root)
        except Exception as e:  # offline hub misses surface as assorted exceptions
            raise DemoDatasetError(
                f"demonstrator dataset {repo_id!r} could not be loaded from {where} ({type(e).__name__}: {e}); "
                "collect it or pass --policy.demo_root=<folder holding meta/info.json>."
            ) from e
        self.repo_id = repo_id
        self.image_key = image_key
        self.n_frames = n_frames
        if image_key not in self.meta.video_keys:
            raise DemoDatasetError(
                f"demonstrator dataset {repo_id!r} has no video feature {image_key!r} "
                f"(it has {self.meta.video_keys}); both datasets must share the camera feature."
            )
        self.image_shape = tuple(self.meta.features[image_key]["shape"])  # (H, W, 3)

        tasks = _episode_tasks(self.meta)
        ranks = _episode_ranks(tasks)
        self.lengths = list(self.meta.episodes["length"])
        self.from_timestamps = list(self.meta.episodes[f"videos/{image_key}/from_timestamp"])
        self.episodes_by_task: dict[str, list[tuple[int, int]]] = {}
        for ep, (task, rank) in enumerate(zip(tasks, ranks, strict=True)):
            self.episodes_by_task.setdefault(task, []).append((ep, rank))

        self.agent_rank: dict[int, int] = {}
        self.agent_task_frequency: dict[str, float] = {}
        self.demo_episodes_by_task = self.episodes_by_task  # every demonstration of a variation
        self._restricted = False  # episodes_by_task holds only the instances seen (True once agent episodes are known)
        if agent_meta is not None:
            self._check_agent(agent_meta, agent_episodes)

        self.threads = threads
        self.prefetch_batches = prefetch_batches
        self.seed = seed
        self.process_index = process_index
        # One stream per training process (its global rank): the processes of a multi-process run pair different
        # samples and must not draw the same demonstrations and frames in the same order. Process 0 keeps
        # default_rng(seed)'s stream.
        spawn_key = (process_index,) if process_index else ()
        self.rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=spawn_key))
        self.wait_s = 0.0  # total time sample() waited for decoding, seconds
        self.last_wait_s = 0.0  # the same for the latest sample() call
        self.served = 0
        self._init_runtime()

    def _init_runtime(self):
        self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="mosaic-demo") if self.threads else None
        self._queues: dict[str, deque] = {}
        self._batch_size: int | None = None
        self._local = threading.local()

    def __getstate__(self):
        state = dict(self.__dict__)
        for key in ("_pool", "_queues", "_local", "_batch_size"):
            state.pop(key, None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._init_runtime()

    def _check_agent(self, agent_meta, agent_episodes: list[int] | None = None) -> None:
        agent_image = tuple(agent_meta.features.get(self.image_key, {}).get("shape", ()))
        if agent_image and agent_image != self.image_shape:
            raise DemoDatasetError(
                f"{self.image_key} is {agent_image} in the agent dataset but {self.image_shape} in the "
                f"demonstrator dataset {self.repo_id!r}; collect both at the same image size."
            )
        all_agent_tasks = _episode_tasks(agent_meta)
        all_ranks = _episode_ranks(all_agent_tasks)
        selected = range(len(all_agent_tasks)) if agent_episodes is None else sorted(set(agent_episodes))
        if any(not 0 <= e < len(all_agent_tasks) for e in selected):
            raise DemoDatasetError(
                f"--dataset.episodes names episodes outside 0..{len(all_agent_tasks) - 1} of the agent dataset."
            )
        agent_tasks = [all_agent_tasks[e] for e in selected]
        missing = sorted(set(agent_tasks) - set(self.episodes_by_task))
        # Up front only for a known selection: a run may train on a subset (--dataset.episodes) that the
        # demonstrator covers; otherwise the first batch of an uncovered variation fails with the same fix.
        if missing and agent_episodes is not None:
            shown = "; ".join(repr(t) for t in missing[:3]) + (" ..." if len(missing) > 3 else "")
            raise DemoDatasetError(
                f"demonstrator dataset {self.repo_id!r} has no episode of {len(missing)} variation(s) of the "
                f"agent dataset: {shown}. Collect them for the demonstrator robot or train on a subset "
                "(--dataset.episodes=[...])."
            )
        self.agent_rank = {e: all_ranks[e] for e in selected}
        self._agent_task = {e: all_agent_tasks[e] for e in selected}
        self._seen_ranks: dict[str, set[int]] = {}
        self._restricted = True
        self.episodes_by_task = {}
        if agent_episodes is not None:  # the run's episodes are known: the same instances on the demonstrator side
            self.observe(list(selected))
        all_lengths = list(agent_meta.episodes["length"])
        lengths = Counter()
        for e in selected:
            lengths[all_agent_tasks[e]] += all_lengths[e]
        total = sum(lengths.values())
        self.agent_task_frequency = {task: n / total for task, n in lengths.items()}

    def observe(self, agent_episodes: list[int]) -> None:
        """Admit the instances of these agent episodes to their variations' demonstrator pools."""
        if not self._restricted:
            return
        changed = set()
        for episode in agent_episodes:
            task, rank = self._agent_task.get(int(episode)), self.agent_rank.get(int(episode))
            if task is None or rank in self._seen_ranks.setdefault(task, set()):
                continue
            self._seen_ranks[task].add(rank)
            changed.add(task)
        for task in changed:
            ranks = self._seen_ranks[task]
            pool = [(ep, rank) for ep, rank in self.demo_episodes_by_task.get(task, []) if rank in ranks]
            # a variation whose instances the demonstrator lacks keeps what it has rather than nothing
            self.episodes_by_task[task] = pool or self.demo_episodes_by_task.get(task, [])

    # -- decoding -------------------------------------------------------------------------------------------

    def _decode(self, episode: int, frame_indices: list[int]) -> Tensor:
        """(n_frames, 3, H, W) uint8 frames of one demonstrator episode.

        torchcodec and LeRobot report a damaged stream ("Could not push packet to decoder", a tolerance assertion
        for frames that are missing) without the file's name; a training run must say which file to fix."""
        video_path = self.meta.root / self.meta.get_video_file_path(episode, self.image_key)
        try:
            frames = self._decode_frames(video_path, episode, frame_indices)
        except Exception as error:  # several exception types for one cause: the file cannot give these frames
            detail = (str(error).strip().splitlines() or [type(error).__name__])[0]
            raise DemoDatasetError(
                f"demonstrator video {video_path} (episode {episode}) does not decode ({detail}): the dataset is "
                f"damaged: check it with `mosaic-data validate {self.meta.root}`, then collect it again"
            ) from None
        if frames.shape[0] != len(frame_indices):
            raise DemoDatasetError(
                f"demonstrator video {video_path} (episode {episode}) gave {frames.shape[0]} of {len(frame_indices)} "
                f"frames: the dataset is damaged: check it with `mosaic-data validate {self.meta.root}`"
            )
        return frames

    def _decode_frames(self, video_path, episode: int, frame_indices: list[int]) -> Tensor:
        timestamps = [self.from_timestamps[episode] + i / self.meta.fps for i in frame_indices]
        try:
            from lerobot.datasets.video_utils import VideoDecoderCache, decode_video_frames_torchcodec

            cache = getattr(self._local, "cache", None)
            if cache is None:  # one decoder cache per thread: a torchcodec decoder is not shared across threads
                cache = self._local.cache = VideoDecoderCache()
            return decode_video_frames_torchcodec(
                video_path, timestamps, 1.0 / self.meta.fps / 2, decoder_cache=cache, return_uint8=True
            )
        except ImportError:
            from lerobot.datasets.video_utils import decode_video_frames

            return decode_video_frames(video_path, timestamps, 1.0 / self.meta.fps / 2, "pyav", return_uint8=True)

    def _draw(self, task: str, exclude_rank: int | None) -> tuple[int, int, list[int]]:
        candidates = self.episodes_by_task.get(task)
        if not candidates:
            raise DemoDatasetError(
                f"demonstrator dataset {self.repo_id!r} has no episode of variation {task!r}; collect it."
            )
        others = [c for c in candidates if c[1] != exclude_rank] or candidates
        episode, rank = others[int(self.rng.integers(len(others)))]
        return episode, rank, demo_frame_indices(self.lengths[episode], self.n_frames, self.rng)

    def _submit(self, task: str) -> tuple[int, Future]:
        episode, rank, indices = self._draw(task, exclude_rank=None)
        return rank, self._pool.submit(self._decode, episode, indices)

    def _take(self, task: str, agent_rank: int | None) -> Tensor:
        queue = self._queues.get(task, ())
        n_candidates = len(self.episodes_by_task.get(task, ()))
        for i, (rank, future) in enumerate(queue):
            if agent_rank is None or rank != agent_rank or n_candidates == 1:
                del queue[i]
                start = time.perf_counter()
                frames = future.result()
                self.wait_s += time.perf_counter() - start
                return frames
        start = time.perf_counter()
        episode, _, indices = self._draw(task, agent_rank)
        frames = self._decode(episode, indices)
        self.wait_s += time.perf_counter() - start
        return frames

    def _top_up(self) -> None:
        if self._pool is None or self._batch_size is None:
            return
        frequency = self.agent_task_frequency or {t: 1 / len(self.episodes_by_task) for t in self.episodes_by_task}
        for task, share in frequency.items():
            if not self.episodes_by_task.get(task):  # no instance of this variation seen yet
                continue
            target = max(1, int(np.ceil(self.prefetch_batches * self._batch_size * share)))
            queue = self._queues.setdefault(task, deque())
            while len(queue) < target:
                queue.append(self._submit(task))

    def sample(self, tasks: list[str], agent_episodes: list[int] | None = None) -> Tensor:
        """(B, n_frames, 3, H, W) uint8 demonstrator frames, one demonstration per agent sample."""
        waited_before = self.wait_s
        if agent_episodes is not None:
            self.observe(agent_episodes)
        elif self._restricted and not self.episodes_by_task:  # no episode indices: every agent instance counts
            self.observe(list(self._agent_task))
        if self._batch_size is None:
            self._batch_size = len(tasks)
            self._top_up()
        frames = []
        for i, task in enumerate(tasks):
            rank = self.agent_rank.get(int(agent_episodes[i])) if agent_episodes is not None else None
            frames.append(self._take(task, rank))
        self.served += len(tasks)
        self.last_wait_s = self.wait_s - waited_before
        self._top_up()  # decode the next batches' demonstrations while this one trains
        return torch.stack(frames)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
