"""What a collection run must produce: one job per (task, robot) dataset, cut into small deterministic shards.

A shard is a block of consecutive episode slots of one variation. Its episodes, seeds and frames depend only
on the job's settings, never on the number of workers or on which worker runs it, and every shard becomes a
small finished LeRobot dataset of its own before it is merged, so that an interrupted run loses at most the
shards that were in flight.

Seeds: episode slot ``k`` of ``variation`` tries instance seeds ``episode_seed(base_seed, variation, k, a)``
for attempts ``a = 0, 1, ...`` until the expert succeeds (see :func:`episode_seed`). With ``action_noise``
(``--action-noise``), each attempt's noise is drawn from that attempt's seed (:mod:`mosaic_data.action_noise`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from mosaic_data.action_noise import ActionNoise
from mosaic_data.collection.schema import FPS, dataset_root, repo_id_for
from mosaic_data.tasks.render_meshes import VISUAL_FACE_BUDGET

EPISODES_PER_SHARD = 10
"""Episode slots per shard: about a minute of work per worker, the most an interruption can lose."""
MAX_ATTEMPTS = 20
"""Expert attempts (fresh seeds) per episode slot before the collection gives up on a variation."""
SEED_STRIDE_VARIATION = 1_000_000
SEED_STRIDE_ATTEMPT = 10_000
MAX_EPISODES = SEED_STRIDE_ATTEMPT
SEED_RULE = "seed = base_seed + 1000000 * variation + 10000 * attempt + slot"


def episode_seed(base_seed: int, variation: int, slot: int, attempt: int) -> int:
    """Instance seed of episode ``slot`` of ``variation`` at expert ``attempt`` (0 first)."""
    return base_seed + SEED_STRIDE_VARIATION * variation + SEED_STRIDE_ATTEMPT * attempt + slot


@dataclass(frozen=True)
class CollectionSettings:
    """Everything that determines a dataset's content: equal settings give equal datasets."""

    task: str
    robot: str
    variations: tuple[int, ...]
    episodes_per_variation: int
    base_seed: int
    image_height: int
    image_width: int
    visual_face_budget: int = VISUAL_FACE_BUDGET
    """The camera's robot meshes (``mosaic_data.tasks.render_meshes``): part of what the frames look like."""
    max_attempts: int = MAX_ATTEMPTS
    episodes_per_shard: int = EPISODES_PER_SHARD
    fps: int = FPS
    seed_rule: str = SEED_RULE
    action_noise: ActionNoise | None = None
    """DART-style noise on the executed actions (the recorded ones are the expert's); None: none. Written to the
    settings only when set, so that a dataset without noise has the settings it had before the option existed."""

    def __post_init__(self) -> None:
        if self.action_noise is not None and not self.action_noise.active:
            object.__setattr__(self, "action_noise", None)  # zero noise is no noise: the same episodes

    def to_json(self) -> dict[str, Any]:
        content = asdict(self)
        content["variations"] = list(self.variations)
        if self.action_noise is None:
            del content["action_noise"]
        else:
            content["action_noise"] = self.action_noise.to_json()
        return content

    @classmethod
    def from_json(cls, content: dict[str, Any]) -> CollectionSettings:
        noise = content.get("action_noise")
        return cls(**{
            **content, "variations": tuple(content["variations"]),
            "action_noise": None if noise is None else ActionNoise.from_json(noise),
        })


@dataclass(frozen=True)
class ShardSpec:
    """Episode slots ``[first_slot, end_slot)`` of one variation of one job."""

    settings: CollectionSettings
    variation: int
    first_slot: int
    end_slot: int
    staging_dir: Path

    @property
    def name(self) -> str:
        return f"v{self.variation:03d}_e{self.first_slot:05d}-{self.end_slot:05d}"

    @property
    def root(self) -> Path:
        """Where the finished shard lives; it only ever appears there complete (renamed into place)."""
        return self.staging_dir / "shards" / self.name

    @property
    def num_episodes(self) -> int:
        return self.end_slot - self.first_slot

    @property
    def is_done(self) -> bool:
        return (self.root / "meta" / "info.json").is_file()


@dataclass(frozen=True)
class DatasetJob:
    """One (task, robot) dataset to collect."""

    settings: CollectionSettings
    output_dir: Path | None

    @property
    def repo_id(self) -> str:
        return repo_id_for(self.settings.task, self.settings.robot)

    @property
    def root(self) -> Path:
        return dataset_root(self.output_dir, self.repo_id)

    @property
    def staging_dir(self) -> Path:
        """Hidden sibling of the dataset, where shards are written; it never looks like a dataset itself."""
        return self.root.parent / f".{self.root.name}.collecting"

    @property
    def total_episodes(self) -> int:
        return len(self.settings.variations) * self.settings.episodes_per_variation

    def shards(self) -> list[ShardSpec]:
        settings = self.settings
        specs = []
        for variation in settings.variations:
            for first in range(0, settings.episodes_per_variation, settings.episodes_per_shard):
                end = min(first + settings.episodes_per_shard, settings.episodes_per_variation)
                specs.append(ShardSpec(settings, variation, first, end, self.staging_dir))
        return specs
