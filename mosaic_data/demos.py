"""Fresh demonstrations for one-shot evaluation: the demonstrator's expert doing the variation on a new instance.

A one-shot policy is shown one video of the demonstrator (the Sawyer) doing the variation, then acts in a
*different* instance with its own robot. At evaluation the demonstration is made on the spot: the scripted
expert runs in the demonstrator's environment from a seed of its own until it succeeds.

Rendering is most of a step's cost on a CPU and a policy looks at only a few frames (MOSAIC: 4), picked from the
episode's length (first, last, middle-segment centres), which is known only at its end. So the expert runs once
without a camera, keeping for every step what that step's frame would show (:class:`FrameState`: the joint positions
the kinematics were last computed from and the model's colours, a few hundred numbers), and at the end only the
picked frames are rendered from those (:meth:`MosaicTaskEnv.render_frame_states`), bit for bit the frames a camera
would have taken during the run (tested). One expert pass per attempt: no second run of the same seed to render the
picked frames (the time this saves is in the README's speed section).
When every frame is wanted (a recording shows the whole demonstration) they are rendered during the pass.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from mosaic_data.rollout import run_expert_episode
from mosaic_data.tasks.base import MosaicTaskEnv
from mosaic_data.tasks.rendering import FrameState

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
    (:data:`mosaic_data.constants.DEMO_RETRY_STRIDE`). Every attempt is one pass of the expert (module docstring).
    """
    for attempt in range(attempts):
        demo_seed = seed + retry_stride * attempt
        if pick_frames is None:  # every frame: render them as the expert goes
            episode = run_expert_episode(env, demo_seed, record_frames=True, record_final_frame=False)
        else:
            episode = run_expert_episode(env, demo_seed, record_final_frame=False, record_frame_states=True)
        if not episode.success:
            continue
        if pick_frames is None:
            indices, frames = list(range(episode.length)), np.stack(episode.frames)
        else:
            indices = [int(i) for i in pick_frames(episode.length)]
            frames = _render_picked(env, episode.frame_states, indices)
        return Demonstration(
            task=env.task_name,
            robot=env.robot_key,
            variation=env.variation_index,
            seed=demo_seed,
            length=episode.length,
            frame_indices=indices,
            frames=frames,
            attempts=attempt + 1,
        )
    raise DemonstrationError(
        f"the {env.robot_key} expert failed on {env.task_name} variation {env.variation_index} for seeds "
        f"{', '.join(str(seed + retry_stride * attempt) for attempt in range(attempts))}"
    )


def _render_picked(env: MosaicTaskEnv, states: Sequence[FrameState], indices: Sequence[int]) -> np.ndarray:
    """The frames at ``indices`` (in that order, repeats allowed) of an episode whose per-frame ``states`` were kept;
    each distinct frame is rendered once. Call it before ``env``'s next reset (the instance's fixtures must be in place)."""
    if not indices or min(indices) < 0 or max(indices) >= len(states):
        raise ValueError(f"frame indices {list(indices)} are outside the demonstration's {len(states)} frames")
    wanted = sorted(set(indices))
    by_step = dict(zip(wanted, env.render_frame_states([states[i] for i in wanted]), strict=True))
    return np.stack([by_step[i] for i in indices])
