"""Save episodes without LeRobot's per-frame image-embedding pass when a dataset has no image columns.

LeRobot's writer runs ``datasets.Dataset.map(embed_table_storage, batched=False)`` on every saved episode
(``lerobot.datasets.io_utils.embed_images``) so that ``Image`` columns carry their bytes into the parquet file.
Our datasets store the camera as video, so no column has anything to embed, yet the map still visits the
episode one row at a time and rebuilds the schema for each (its cost per frame is in the README's speed
section). :func:`skip_needless_image_embedding`
makes the writer skip that pass exactly when no feature needs embedding (``datasets``' own
``require_storage_embed`` test); a dataset with image columns goes through LeRobot's code unchanged. The
parquet files hold the same tables and schema; only the cache fingerprint that ``map`` leaves in the schema's
metadata is missing, which nothing reads back (tested, and LeRobot loads the same samples from both).
"""

from __future__ import annotations

from typing import Any


def skip_needless_image_embedding() -> None:
    """Install the check in LeRobot's dataset writer for this process; idempotent."""
    from lerobot.datasets import dataset_writer

    if not getattr(dataset_writer.embed_images, "skips_tables_without_images", False):
        dataset_writer.embed_images = _embedding_only_if_needed(dataset_writer.embed_images)


def _embedding_only_if_needed(embed_images):
    from datasets.features.features import require_storage_embed

    def embed_images_if_any(dataset: Any):
        if any(require_storage_embed(feature) for feature in dataset.features.values()):
            return embed_images(dataset)
        return dataset

    embed_images_if_any.skips_tables_without_images = True
    embed_images_if_any.__doc__ = embed_images.__doc__
    return embed_images_if_any
