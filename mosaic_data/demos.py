"""Fresh demonstrations for one-shot evaluation: the demonstrator's expert doing the variation on a new instance.

A one-shot policy is shown one video of the demonstrator (the Sawyer) doing the variation, then acts in a
*different* instance with its own robot. At evaluation the demonstration is made on the spot: the scripted
expert runs in the demonstrator's environment from a seed of its own until it succeeds.

Rendering is most of a step's cost on a CPU and a policy looks at only a few frames (MOSAIC: 4), so the
expert first runs without a camera to learn the episode's length, then the same seed is replayed (the
simulation is deterministic) rendering only the frames that are asked for.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from mosaic_data.rollout import run_expert_episode
from mosaic_data.tasks.base import MosaicTaskEnv

DEMO_ATTEMPTS = 5
"""Seeds tried (``seed``, ``seed + retry_stride``, ...) before giving up on a demonstration; the experts are >= 95%."""


class DemonstrationError(RuntimeError):
    """The demonstrator's expert failed on every seed it was given."""


@dataclass
class Demonstration:
    """One successful demonstration: frames (K, H, W, 3) uint8 at ``frame_indices`` of its ``length`` frames."""

    task: str
    robot: str
    variation: int
    seed: int
    length: int
    frame_indices: list[int]
    frames: np.ndarray
    attempts: int = 1


def record_demonstration(
    env: MosaicTaskEnv,
    seed: int,
    pick_frames: Callable[[int], Sequence[int]] | None = None,
    attempts: int = DEMO_ATTEMPTS,
    retry_stride: int = 1,
) -> Demonstration:
    """Run ``env``'s expert from ``seed`` (then ``seed + retry_stride``, ...) until it succeeds; return its frames.

    The demonstration has one frame per action, as a recorded dataset episode (the frame after the final
    action is left out). ``pick_frames(length)`` chooses the frame indices to render (all when None).
    ``retry_stride`` spaces the retries' seeds: evaluation keeps them clear of the next episode's seed
    (:data:`mosaic_data.constants.DEMO_RETRY_STRIDE`).
    """
    for attempt in range(attempts):
        demo_seed = seed + retry_stride * attempt
        probe = run_expert_episode(env, demo_seed)
        if not probe.success:
            continue
        indices = list(range(probe.length)) if pick_frames is None else [int(i) for i in pick_frames(probe.length)]
        if not indices or min(indices) < 0 or max(indices) >= probe.length:
            raise ValueError(f"frame indices {indices} are outside the demonstration's {probe.length} frames")
        wanted = sorted(set(indices))
        replay = run_expert_episode(
            env, demo_seed, record_frames=True, record_final_frame=False, frame_steps=set(wanted)
        )
        if replay.length != probe.length or len(replay.frames) != len(wanted):
            raise RuntimeError(
                f"the replay of seed {demo_seed} diverged from its first run ({replay.length} vs {probe.length} "
                "steps): the simulation is not deterministic here"
            )
        by_step = dict(zip(wanted, replay.frames, strict=True))
        return Demonstration(
            task=env.task_name,
            robot=env.robot_key,
            variation=env.variation_index,
            seed=demo_seed,
            length=probe.length,
            frame_indices=indices,
            frames=np.stack([by_step[i] for i in indices]),
            attempts=attempt + 1,
        )
    raise DemonstrationError(
        f"the {env.robot_key} expert failed on {env.task_name} variation {env.variation_index} for seeds "
        f"{', '.join(str(seed + retry_stride * attempt) for attempt in range(attempts))}"
    )
