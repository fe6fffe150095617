"""Hand-relative position targets: the action head predicts where to go as an offset from where the hand is.

The datasets and the environments speak absolute world-frame targets (x, y, z, rotation, gripper). A policy
that predicts absolute positions from one camera frame must first locate its own hand in the image: at 48x88
a centimetre is half a pixel, and an error of the size of one step's move turns "go on" into "stay" (the door
policy, seeing itself 3 cm higher than it was at the bottom of the descent, sent the hand up and down in front
of the handle until the horizon). An offset from the hand only needs the direction and the distance of the
next move, which the frame shows whatever the hand's exact position (robomimic and most behaviour cloning on
robosuite predict relative end-effector moves for this reason).

The conversion happens inside the policy, on the normalised values the processors produce, so the datasets,
the processors and every consumer of the policy's actions keep absolute targets: each chunk is made relative
to the hand position (``observation.state`` x, y, z) of the frame that predicts it, and the predicted offsets
are added back to the current hand position before the postprocessor unnormalises them. The offsets have
their own [-1, 1] range, measured over the training dataset's chunks with LeRobot's
``compute_relative_action_stats`` and kept in the checkpoint with the two normalisers' position statistics.
Rotation and gripper targets stay absolute.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from lerobot.utils.constants import ACTION, OBS_STATE

from mosaic_data.constants import STATE_NAMES

POSITION_DIMS = 3
"""Action dims 0-2 (x, y, z) are made relative; observation.state dims 0-2 are the hand's x, y, z."""
ABSOLUTE_ACTION_NAMES = ["rx", "ry", "rz", "gripper"]
"""The action dims kept absolute, by name (LeRobot's ``exclude_joints``)."""
NORMALISER_EPS = 1e-8
"""LeRobot's NormalizerProcessorStep epsilon (MEAN_STD divides by std + eps)."""


class HandRelativeTargets(nn.Module):
    """Converts normalised absolute position targets to normalised hand offsets and back (see the module docstring).

    Buffers (saved with the policy): the state normaliser's mean/std and the action normaliser's min/max of the
    position dims, and the min/max of the offsets over the dataset's chunks.
    """

    def __init__(self) -> None:
        super().__init__()
        for name, value in (
            ("state_mean", 0.0), ("state_std", 1.0), ("action_min", -1.0), ("action_max", 1.0),
            ("offset_min", -1.0), ("offset_max", 1.0),
        ):
            self.register_buffer(name, torch.full((POSITION_DIMS,), value))

    @torch.no_grad()
    def fit(self, stats: dict, offsets: dict[str, np.ndarray]) -> HandRelativeTargets:
        """Take the dataset's normaliser statistics (``dataset_meta.stats``) and the offsets' min/max."""
        for buffer, (key, stat) in (
            ("state_mean", (OBS_STATE, "mean")), ("state_std", (OBS_STATE, "std")),
            ("action_min", (ACTION, "min")), ("action_max", (ACTION, "max")),
        ):
            getattr(self, buffer).copy_(torch.as_tensor(np.asarray(stats[key][stat])[:POSITION_DIMS]))
        low = torch.as_tensor(np.asarray(offsets["min"])[:POSITION_DIMS], dtype=torch.float32)
        high = torch.as_tensor(np.asarray(offsets["max"])[:POSITION_DIMS], dtype=torch.float32)
        margin = 0.05 * (high - low)  # room for a policy to ask a little more than the data shows
        self.offset_min.copy_(low - margin)
        self.offset_max.copy_(high + margin)
        return self

    def _hand(self, state: Tensor) -> Tensor:
        """World hand position (..., 3) from the normalised state (..., S)."""
        return state[..., :POSITION_DIMS] * (self.state_std + NORMALISER_EPS) + self.state_mean

    def to_relative(self, chunks: Tensor, state: Tensor) -> Tensor:
        """Normalised absolute chunks (..., chunk, A) -> normalised offsets from the hand of ``state`` (..., S)."""
        position = _from_unit_range(chunks[..., :POSITION_DIMS], self.action_min, self.action_max)
        offset = position - self._hand(state).unsqueeze(-2)
        scaled = _to_unit_range(offset, self.offset_min, self.offset_max).clamp(-1.0, 1.0)
        return torch.cat([scaled, chunks[..., POSITION_DIMS:]], dim=-1)

    def to_absolute(self, chunks: Tensor, state: Tensor) -> Tensor:
        """Normalised offsets (..., chunk, A) from the hand of ``state`` (..., S) -> normalised absolute targets."""
        offset = _from_unit_range(chunks[..., :POSITION_DIMS], self.offset_min, self.offset_max)
        position = self._hand(state).unsqueeze(-2) + offset
        return torch.cat([_to_unit_range(position, self.action_min, self.action_max), chunks[..., POSITION_DIMS:]], dim=-1)


def _to_unit_range(value: Tensor, low: Tensor, high: Tensor) -> Tensor:
    """[low, high] -> [-1, 1], as LeRobot's MIN_MAX normalisation maps."""
    return 2.0 * (value - low) / (high - low) - 1.0


def _from_unit_range(normalised: Tensor, low: Tensor, high: Tensor) -> Tensor:
    """[-1, 1] -> [low, high], the inverse of :func:`_to_unit_range`."""
    return (normalised + 1.0) / 2.0 * (high - low) + low


def check_state_names(state_names: list[str] | None) -> None:
    """The state must start with the hand's x, y, z (the MOSAIC datasets' layout)."""
    if state_names is None or list(state_names[:POSITION_DIMS]) != list(STATE_NAMES[:POSITION_DIMS]):
        raise ValueError(
            "`hand_relative_targets` needs observation.state to start with the hand's x, y, z "
            f"(names {list(STATE_NAMES[:POSITION_DIMS])}), got {state_names}: train on a MOSAIC dataset or pass "
            "--policy.hand_relative_targets=false."
        )


def dataset_offset_stats(root: Path | str, features: dict, chunk: int, episodes: list[int] | None = None) -> dict:
    """Statistics of every chunk's position targets minus the hand position of its first frame, over the
    dataset's episodes (LeRobot's ``compute_relative_action_stats``)."""
    import pyarrow.dataset as pa_ds
    from lerobot.datasets.compute_stats import compute_relative_action_stats

    table = pa_ds.dataset(sorted(Path(root, "data").glob("*/*.parquet")), format="parquet").to_table(
        columns=[ACTION, OBS_STATE, "episode_index"],
        filter=pa_ds.field("episode_index").isin(episodes) if episodes is not None else None,
    )
    columns = {
        ACTION: np.stack(table.column(ACTION).to_numpy(zero_copy_only=False)),
        OBS_STATE: np.stack(table.column(OBS_STATE).to_numpy(zero_copy_only=False)),
        "episode_index": table.column("episode_index").to_numpy(),
    }
    return compute_relative_action_stats(columns, features, chunk, exclude_joints=ABSOLUTE_ACTION_NAMES)
