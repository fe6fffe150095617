"""Where an evaluation episode's demonstration comes from: the demonstrator's expert on a fresh instance (the
paper's protocol), or an episode of a held-out demonstrator dataset (`mosaic-eval --demo-dataset`).

:class:`ExpertDemoSource` and :func:`policy_frames` are also what ``lerobot-eval --env.type=mosaic``'s
environment makes its demonstrations with (:mod:`.lerobot_env`): one source for both front-ends.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mosaic_data.constants import CAMERA_KEY, DEMO_RETRY_STRIDE, IMAGE_HEIGHT, IMAGE_WIDTH
from mosaic_data.demos import Demonstration, record_demonstration
from mosaic_data.tasks import get_task_class, make_task_env

from .env_cache import EnvCache
from .options import EvaluationError

DEMONSTRATOR = "sawyer"
PickFrames = Callable[[int], Sequence[int]] | None


def policy_frames(n_frames: int | None) -> PickFrames:
    """The frames of a demonstration a policy conditions on, ``n_frames`` of them (first, last, middle-segment
    centres, as the policy picks them itself); None (all frames) when ``n_frames`` is None."""
    if n_frames is None:
        return None
    from mosaic_policy.common.paired_sampling import demo_frame_indices

    return lambda length: demo_frame_indices(length, n_frames)


@dataclass(frozen=True)
class DemoSourceSpec:
    """Plain-data description of a demo source, built again inside every worker process."""

    dataset: str | None = None  # a local LeRobot dataset folder; None: the demonstrator's expert, fresh seeds
    robot: str = DEMONSTRATOR


class ExpertDemoSource:
    """A new demonstration per episode, by the demonstrator's scripted expert (one environment kept per task, serving
    all its variations; built on first use: no GL context before a worker forks)."""

    def __init__(self, robot: str = DEMONSTRATOR, image_hw: tuple[int, int] = (IMAGE_HEIGHT, IMAGE_WIDTH)) -> None:
        self.robot = robot
        self.image_hw = image_hw
        self._envs = EnvCache()

    def demonstration(self, task: str, variation: int, seed: int, pick_frames: PickFrames) -> Demonstration:
        """The expert's demonstration from ``seed`` (an episode's demo seed, see :mod:`.seeds`); its retries step
        by DEMO_RETRY_STRIDE, clear of the other episodes' seeds."""
        height, width = self.image_hw
        env = self._envs.get(task, lambda: make_task_env(task, variation, self.robot, image_height=height, image_width=width))
        env.set_variation(variation)  # one scene per task serves all its variations (a seeded reset follows)
        return record_demonstration(env, seed, pick_frames, retry_stride=DEMO_RETRY_STRIDE)

    def close(self) -> None:
        self._envs.close()


class DatasetDemoSource:
    """Demonstrations drawn from a recorded demonstrator dataset: for every episode, one recorded episode of the
    same variation (same LeRobot task string), chosen by the episode's demo seed."""

    def __init__(self, root: str | Path, image_hw: tuple[int, int]) -> None:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        from mosaic_data.collection.schema import repo_id_of

        root = Path(root)
        self.dataset = LeRobotDataset(repo_id_of(root), root=root)
        shape = tuple(self.dataset.meta.features.get(CAMERA_KEY, {}).get("shape", ()))
        if shape[:2] != tuple(image_hw):
            raise EvaluationError(
                f"demo dataset {root} has {CAMERA_KEY} of shape {shape} but the policy sees {image_hw[0]}x{image_hw[1]} "
                "frames: collect the demonstrations at the policy's image size"
            )
        episodes = self.dataset.meta.episodes
        self._episodes_of: dict[str, list[tuple[int, int, int]]] = {}  # description -> (episode, first frame, length)
        self._records: dict[int, dict] = {}
        for index in range(len(episodes)):
            record = episodes[index]
            start = int(record["dataset_from_index"])
            length = int(record["dataset_to_index"]) - start
            episode = int(record["episode_index"])
            self._records[episode] = record
            for description in record["tasks"]:
                self._episodes_of.setdefault(description, []).append((episode, start, length))
        self.root = root

    def check_covers(self, task: str, variations: Sequence[int]) -> None:
        """Fail before any rollout if a variation has no recorded demonstration."""
        task_class = get_task_class(task)
        for variation in variations:
            description = task_class.variations[variation].description
            if description not in self._episodes_of:
                raise EvaluationError(
                    f"demo dataset {self.root} has no episode of {task} variation {variation} ({description!r}): "
                    f"collect it with `mosaic-data collect --task {task} --robot sawyer --variations {variation}`"
                )

    def demonstration(self, task: str, variation: int, seed: int, pick_frames: PickFrames) -> Demonstration:
        description = get_task_class(task).variations[variation].description
        candidates = self._episodes_of.get(description)
        if not candidates:
            raise EvaluationError(f"demo dataset {self.root} has no episode of {task} variation {variation}")
        choice = int(np.random.default_rng(seed).integers(len(candidates)))
        episode, start, length = candidates[choice]
        indices = list(range(length)) if pick_frames is None else [int(i) for i in pick_frames(length)]
        try:
            frames = [self._frame(start + i) for i in indices]
        except Exception as error:  # torchcodec and LeRobot raise several types for a damaged stream, none names the file
            raise EvaluationError(
                f"demo video {self.video_file(episode)} (episode {episode}) does not decode ({_first_line(error)}): "
                f"{self._damaged_fix}"
            ) from None
        return Demonstration(task, DEMONSTRATOR, variation, seed, length, indices, np.stack(frames))

    def _frame(self, index: int) -> np.ndarray:
        image = self.dataset[index][CAMERA_KEY]  # (3, H, W) float in [0, 1]
        return (image.permute(1, 2, 0).clamp(0, 1) * 255).round().byte().numpy()

    def video_file(self, episode: int) -> Path:
        """The video file that holds ``episode``'s camera frames (LeRobot packs several episodes into one file)."""
        record = self._records[episode]
        return self.root / self.dataset.meta.video_path.format(
            video_key=CAMERA_KEY,
            chunk_index=int(record[f"videos/{CAMERA_KEY}/chunk_index"]),
            file_index=int(record[f"videos/{CAMERA_KEY}/file_index"]),
        )

    @property
    def _damaged_fix(self) -> str:
        return f"the demo dataset is damaged: check it with `mosaic-data validate {self.root}`, then collect it again"

    def check_videos(self, tasks: dict[str, Sequence[int]]) -> None:
        """Decode, before any rollout, every video holding an episode of ``tasks``' variations, and check that each
        such episode decodes to as many frames as its metadata says: a damaged file fails naming itself, and a
        lightly damaged one (a few frames lost, no decoder error) does not pass unnoticed."""
        wanted: dict[Path, list[int]] = {}
        for task, variations in tasks.items():
            task_class = get_task_class(task)
            for variation in variations:
                for episode, _, _ in self._episodes_of.get(task_class.variations[variation].description, []):
                    wanted.setdefault(self.video_file(episode), []).append(episode)
        fps = self.dataset.meta.fps
        for path, episodes in wanted.items():
            frame_numbers, error = _decoded_frame_numbers(path, fps)
            if error is not None:
                raise EvaluationError(f"demo video {path} does not decode ({error}): {self._damaged_fix}")
            for episode in episodes:
                record = self._records[episode]
                first = round(float(record[f"videos/{CAMERA_KEY}/from_timestamp"]) * fps)
                end = round(float(record[f"videos/{CAMERA_KEY}/to_timestamp"]) * fps)
                decoded = sum(first <= number < end for number in frame_numbers)
                length = int(record["length"])
                if decoded != length:
                    raise EvaluationError(
                        f"demo video {path} decodes to {decoded} frames of episode {episode}, its metadata says "
                        f"{length}: {self._damaged_fix}"
                    )

    def close(self) -> None:
        pass


def _decoded_frame_numbers(path: Path, fps: int) -> tuple[list[int], str | None]:
    """Frame numbers (timestamp x fps) of every frame ``path`` decodes to, and the error that stopped it, if any."""
    import av

    if not path.is_file():
        return [], "the file is missing"
    numbers: list[int] = []
    try:
        with av.open(str(path)) as container:
            for frame in container.decode(video=0):
                numbers.append(round(frame.time * fps) if frame.time is not None else len(numbers))
    except Exception as error:  # av raises many error types for damaged streams
        return numbers, f"{type(error).__name__}: {_first_line(error)} after {len(numbers)} frames"
    return numbers, None


def _first_line(error: BaseException) -> str:
    return (str(error).strip().splitlines() or [type(error).__name__])[0]


def build_demo_source(spec: DemoSourceSpec, image_hw: tuple[int, int]):
    if spec.dataset is None:
        return ExpertDemoSource(spec.robot, image_hw)
    return DatasetDemoSource(spec.dataset, image_hw)
